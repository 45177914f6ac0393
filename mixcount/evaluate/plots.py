"""PNG plots of the dataset statistics (matplotlib, Agg backend: no display needed).

Each plot is drawn from the histograms already in the stats dict, so the PNGs and stats.json always
show the same numbers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # headless; must precede pyplot
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from mixcount.evaluate.stats import TIERS  # noqa: E402

DPI = 100
PLOT_FILES = (
    "objects_per_scene.png", "classes_per_scene.png", "class_imbalance.png", "visibility.png",
    "splits.png", "caption_length.png", "kept_vs_spawned.png",
)


def _int_bar(ax: Any, hist: dict[str, list[int]], color: str, label: str | None = None, width: float = 0.9) -> None:
    if hist["values"]:
        ax.bar(hist["values"], hist["counts"], width=width, color=color, label=label)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    else:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)


def _edge_bar(ax: Any, hist: dict[str, list[Any]], color: str, label: str | None = None, alpha: float = 1.0) -> None:
    edges, counts = hist["edges"], hist["counts"]
    if sum(counts):
        widths = [b - a for a, b in zip(edges[:-1], edges[1:])]
        ax.bar(edges[:-1], counts, width=widths, align="edge", color=color, alpha=alpha, label=label, edgecolor="white")
    else:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)


def _save(fig: Any, path: Path) -> Path:
    for ax in fig.axes:  # counts are integers: no 0.25 ticks on the count axes
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def write_plots(stats: dict[str, Any], out_dir: str | Path) -> list[Path]:
    """Write one PNG per statistic into ``out_dir`` (created); returns the paths (see PLOT_FILES)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []

    fig, ax = plt.subplots(figsize=(6, 4))
    _int_bar(ax, stats["objects_per_scene"]["histogram"], "#3b75af")
    ax.set(title="Counted objects per scene", xlabel="objects", ylabel="scenes")
    paths.append(_save(fig, out_dir / "objects_per_scene.png"))

    fig, ax = plt.subplots(figsize=(6, 4))
    _int_bar(ax, stats["classes_per_scene"]["histogram"], "#519e3e")
    ax.set(title="Classes per scene", xlabel="classes", ylabel="scenes")
    paths.append(_save(fig, out_dir / "classes_per_scene.png"))

    fig, ax = plt.subplots(figsize=(6, 4))
    _edge_bar(ax, stats["class_imbalance"]["histogram"], "#ef8636")
    ax.set(title="Class imbalance (most / least common class)", xlabel="ratio", ylabel="scenes")
    paths.append(_save(fig, out_dir / "class_imbalance.png"))

    fig, ax = plt.subplots(figsize=(6, 4))
    _edge_bar(ax, stats["visibility"]["counted"]["histogram"], "#3b75af", "counted", 0.8)
    if sum(stats["visibility"]["distractor"]["histogram"]["counts"]):
        _edge_bar(ax, stats["visibility"]["distractor"]["histogram"], "#c53a32", "distractor", 0.6)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left")
    ax.set(title="Visibility of annotated objects", xlabel="visible fraction", ylabel="annotations", xlim=(0, 1))
    paths.append(_save(fig, out_dir / "visibility.png"))

    fig, axes = plt.subplots(1, 2, figsize=(8, 4))
    names = list(stats["splits"])
    axes[0].bar(names, [stats["splits"][s]["scenes"] for s in names], color="#8d69b8")
    axes[0].set(title="Scenes per split", ylabel="scenes")
    axes[1].bar(names, [stats["splits"][s]["objects"] for s in names], color="#3b75af", label="counted")
    axes[1].bar(
        names, [stats["splits"][s]["distractors"] for s in names], color="#c53a32", label="distractors",
        bottom=[stats["splits"][s]["objects"] for s in names],
    )
    axes[1].set(title="Objects per split", ylabel="annotations")
    axes[1].legend()
    paths.append(_save(fig, out_dir / "splits.png"))

    fig, axes = plt.subplots(1, len(TIERS), figsize=(10, 3.5))
    for ax, tier, color in zip(axes, TIERS, ("#3b75af", "#519e3e", "#ef8636")):
        _int_bar(ax, stats["caption_length"][tier]["histogram"], color)
        ax.set(title=f"{tier} captions", xlabel="words", ylabel="categories")
    paths.append(_save(fig, out_dir / "caption_length.png"))
    paths.append(_kept_vs_spawned(stats.get("density"), out_dir / "kept_vs_spawned.png"))
    return paths


def _kept_vs_spawned(density: dict[str, Any] | None, path: Path) -> Path:
    """Left: counted objects spawned and kept per scene (histograms). Right: drop reasons of counted
    objects and distractors ("no data" panels for a dataset without scene metadata)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    if density is None or not density["summary"]["scenes"]:
        for ax in axes:
            ax.text(0.5, 0.5, "no data (no scene metadata.json)", ha="center", va="center", transform=ax.transAxes)
        return _save(fig, path)
    _edge_bar(axes[0], density["spawned_per_scene"]["histogram"], "#9aa7b4", "spawned", 0.7)
    _edge_bar(axes[0], density["kept_per_scene"]["histogram"], "#3b75af", "kept", 0.8)
    d = density["summary"]
    axes[0].legend(loc="upper right")
    axes[0].set(title=f"Counted objects per scene (retention {d['retention'] or 0:.2f})", xlabel="objects",
                ylabel="scenes")
    axes[0].yaxis.set_major_locator(MaxNLocator(integer=True))  # scenes are counted in whole numbers
    reasons = sorted(set(d["counted_drops"]) | set(d["distractor_drops"]))
    if reasons:
        counted = [d["counted_drops"].get(r, 0) for r in reasons]
        axes[1].barh(reasons, counted, color="#3b75af", label="counted")
        axes[1].barh(reasons, [d["distractor_drops"].get(r, 0) for r in reasons], left=counted, color="#c53a32",
                     label="distractors")
        axes[1].legend(loc="lower right")
    else:
        axes[1].text(0.5, 0.5, "nothing dropped", ha="center", va="center", transform=axes[1].transAxes)
    axes[1].set(title="Drop reasons", xlabel="objects")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
