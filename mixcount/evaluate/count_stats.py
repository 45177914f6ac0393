"""Count targets against what scenes kept (issue 37): read by ``mixcount stats`` and ``bench/counts.py``.

From the finished scenes' ``metadata.json`` (``count_target`` beside ``counts``) and the regenerated seeds'
records under ``scenes/.rejected/`` (a ``count_target`` diagnostic with the verdict): how many scenes kept
exactly their target and how many within the tolerance, the Kolmogorov-Smirnov distance between the kept
totals and the target distribution (the empirical target draws when the distribution is not known here),
counts per bin of both, the per-class imbalance (largest / smallest kept class against the drawn ratio,
and how far each class ended from its drawn count), and the scenes regenerated or brought to target, with
why. Pure Python and numpy: no bpy, no catalog.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

import numpy as np


def scene_record(meta: Mapping[str, Any]) -> Optional[dict[str, Any]]:
    """One finished scene's target against what it kept, or None for a scene without a count target."""
    target = meta.get("count_target")
    if not target:
        return None
    kept_per = {str(k): int(v) for k, v in (meta.get("counts") or {}).items()}
    per_t = {str(k): int(v) for k, v in target["per_class"].items()}
    diag: dict[str, Any] = next((d for d in meta.get("diagnostics", []) if d.get("kind") == "count_target"), {})
    objects = meta.get("objects", [])
    # spawned: the bodies that entered the scene (a reserve body no top-up needed never did)
    spawned = sum(1 for o in objects if o.get("role") == "counted" and o.get("reason") != "count_reserve")
    removed = sum(1 for o in objects if o.get("reason") == "count_surplus")
    rest: dict[str, Any] = next((d for d in meta.get("diagnostics", []) if d.get("kind") == "count_rest"), {})
    verify = next((d for d in meta.get("diagnostics", []) if d.get("kind") == "count_rest_verify"), None)
    return {"scene_id": meta.get("scene_id"), "seed": meta.get("seed"), "target": int(target["total"]),
            "kept": sum(kept_per.get(c, 0) for c in per_t), "per_class_target": per_t,
            "per_class_kept": {c: kept_per.get(c, 0) for c in per_t}, "imbalance": target.get("imbalance"),
            "spawned": spawned, "surplus_removed": removed, "distribution": target.get("distribution"),
            "topped_up": int(diag.get("topped_up", 0)), "topup_rounds": int(diag.get("topup_rounds", 0)),
            "rest_fell": int(rest.get("fell", 0)), "rest_largest_drop": rest.get("largest_drop_x_size"),
            "rest_largest_displacement": rest.get("largest_displacement_x_size"),
            "median_visible_px": diag.get("median_visible_px"), "too_small": diag.get("too_small"),
            "rest_verify": None if verify is None else {k: verify.get(k) for k in
                                                        ("fell", "fell_over_half_size", "largest_drop_x_size")}}


def rejected_record(rec: Mapping[str, Any]) -> Optional[dict[str, Any]]:
    """A regenerated seed's record (``scenes/.rejected/<id>.json``) -> scene, status and why (the count
    verdict when it was one; else the status the worker gave: empty, a failed visibility re-check)."""
    diag = next((d for d in rec.get("diagnostics", []) if d.get("kind") == "count_target"), None)
    why = rec.get("status", "rejected")
    if diag is not None and diag.get("verdict", "ok") != "ok":
        why = f"{diag['verdict']}: kept {diag['kept']} of {diag['total']}"
    elif any(d.get("kind") == "recheck_failed" for d in rec.get("diagnostics", [])):
        why = "visibility re-check failed"
    return {"scene_id": rec.get("scene_id"), "seed": rec.get("seed"), "why": why,
            "target": None if diag is None else diag.get("total"), "kept": None if diag is None else diag.get("kept")}


def read_dataset(root: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(scene records with a count target, regenerated seeds' records) of a dataset folder."""
    scenes_dir = Path(root) / "scenes"
    rows = []
    for meta_path in sorted(scenes_dir.glob("*/metadata.json")):
        rec = scene_record(json.loads(meta_path.read_text()))
        if rec is not None:
            rows.append(rec)
    rejected = []
    for path in sorted((scenes_dir / ".rejected").glob("*.json")):
        one = rejected_record(json.loads(path.read_text()))
        if one is not None:
            rejected.append(one)
    return rows, rejected


def ks_distance(kept: Sequence[int], target_cdf: Any) -> float:
    """sup |F_kept - F_target| over the integers (both step functions jump only at integers)."""
    k = np.sort(np.asarray(kept, dtype=np.int64))
    if len(k) == 0:
        return float("nan")
    xs = np.arange(int(k.min()) - 1, int(k.max()) + 1)
    f_kept = np.searchsorted(k, xs, side="right") / len(k)
    gaps = np.abs(f_kept - target_cdf(xs))
    return float(gaps.max())


def empirical_cdf(values: Sequence[int]) -> Any:
    v = np.sort(np.asarray(values, dtype=np.int64))
    return lambda xs: np.searchsorted(v, np.asarray(xs), side="right") / max(len(v), 1)


def bins_of(values: Iterable[int], edges: Sequence[int]) -> list[int]:
    return [int(c) for c in np.histogram(np.asarray(list(values)), bins=np.asarray(edges))[0]]


def summarise_counts(rows: Sequence[Mapping[str, Any]], rejected: Sequence[Mapping[str, Any]] = (),
                     target_cdf: Any = None, bin_width: int = 0) -> dict[str, Any]:
    """The figures of issue 37 for a set of scenes (see the module docstring). ``target_cdf`` is the
    target distribution's CDF (:meth:`CountDistribution.cdf`); without it the scenes' drawn targets."""
    if not rows:
        return {"scenes": 0, "regenerated": len(rejected), "regenerated_scenes": list(rejected)}
    targets = np.array([r["target"] for r in rows])
    kept = np.array([r["kept"] for r in rows])
    diff = kept - targets
    tol = np.maximum(2, np.floor(0.05 * targets))
    hi = int(max(targets.max(), kept.max()))
    width = bin_width or max(1, int(math.ceil(hi / 10 / 5)) * 5)
    edges = list(range(0, hi + width + 1, width))
    class_offs = [abs(r["per_class_kept"][c] - r["per_class_target"][c]) for r in rows for c in r["per_class_target"]]
    ratios = []
    for r in rows:
        vals = [v for v in r["per_class_kept"].values()]
        if r.get("imbalance") is not None and len(vals) > 1 and min(vals) > 0:
            ratios.append({"scene_id": r["scene_id"], "drawn": r["imbalance"], "kept": round(max(vals) / min(vals), 3),
                           "target": round(max(r["per_class_target"].values()) / min(r["per_class_target"].values()), 3)})
    brought = [{"scene_id": r["scene_id"], "spawned": r["spawned"], "surplus_removed": r["surplus_removed"],
                "target": r["target"], "kept": r["kept"]} for r in rows if r["surplus_removed"] > 0]
    small = [{"scene_id": r["scene_id"], **r["too_small"]} for r in rows if r.get("too_small")]
    return {
        "scenes": len(rows), "exact": int((diff == 0).sum()), "exact_share": round(float((diff == 0).mean()), 4),
        "within_tolerance": int((np.abs(diff) <= tol).sum()),
        "max_abs_miss": int(np.abs(diff).max()),
        "ks_distance": round(ks_distance(kept.tolist(), target_cdf or empirical_cdf(targets.tolist())), 4),
        "ks_against": "distribution" if target_cdf is not None else "drawn targets",
        "bins": {"edges": edges, "target": bins_of(targets, edges), "kept": bins_of(kept, edges)},
        "target_median": float(np.median(targets)), "kept_median": float(np.median(kept)),
        "per_class": {"classes": len(class_offs), "within_one": int(sum(1 for d in class_offs if d <= 1)),
                      "exact": int(sum(1 for d in class_offs if d == 0)), "max_off": int(max(class_offs, default=0))},
        "imbalance": ratios,
        "regenerated": len(rejected), "regenerated_share_of_kept": round(len(rejected) / len(rows), 4),
        "regenerated_scenes": list(rejected), "brought_to_target": len(brought),
        "surplus_removed": int(sum(r["surplus_removed"] for r in rows)),
        "spawned_per_target": round(float(sum(r["spawned"] for r in rows) / max(1, targets.sum())), 4),
        "topped_up_scenes": int(sum(1 for r in rows if r.get("topped_up"))),
        "topped_up_bodies": int(sum(r.get("topped_up", 0) for r in rows)),
        # the rest check after the take-out: bodies that fell (took the re-simulated pose), the largest drop
        # and displacement (x the body's size) seen in any scene
        "rest_fell": int(sum(r.get("rest_fell", 0) for r in rows)),
        "rest_largest_drop": max((r.get("rest_largest_drop") or 0.0 for r in rows), default=0.0),
        "rest_largest_displacement": max((r.get("rest_largest_displacement") or 0.0 for r in rows), default=0.0),
        "too_small": small,
        **_rest_verified(rows),
    }


def _rest_verified(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """With ``scene.count_rest_verify`` (a bench's): over the scenes checked once more, whole, by the
    settle's rule: how many, in how many a body would still fall more than the tolerance, how many bodies,
    how many more than half their size, the largest drop (x size). Empty when no scene was checked."""
    checked = [r["rest_verify"] for r in rows if r.get("rest_verify")]
    if not checked:
        return {}
    return {"rest_verified": {"scenes": len(checked), "scenes_with_a_fall": sum(1 for v in checked if v["fell"]),
                              "fell": int(sum(v["fell"] for v in checked)),
                              "fell_over_half_size": int(sum(v.get("fell_over_half_size") or 0 for v in checked)),
                              "largest_drop_x_size": max(float(v["largest_drop_x_size"]) for v in checked)}}


def plot_counts(summary: Mapping[str, Any], rows: Sequence[Mapping[str, Any]], out: Path) -> Path:
    """Target against kept: the two histograms on the summary's bins and kept over target per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    edges = np.asarray(summary["bins"]["edges"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    centres = (edges[:-1] + edges[1:]) / 2
    w = (edges[1] - edges[0]) * 0.4
    a.bar(centres - w / 2, summary["bins"]["target"], width=w, label="target")
    a.bar(centres + w / 2, summary["bins"]["kept"], width=w, label="kept")
    a.set_xlabel("visible counted objects per image")
    a.set_ylabel("scenes")
    a.set_title(f"KS distance {summary['ks_distance']}")
    a.legend()
    t = [r["target"] for r in rows]
    k = [r["kept"] for r in rows]
    b.scatter(t, k, s=10)
    top = max(t + k) if t else 1
    b.plot([0, top], [0, top], lw=0.8, color="grey")
    b.set_xlabel("target")
    b.set_ylabel("kept")
    b.set_title(f"{summary['exact']} of {summary['scenes']} exactly on target")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def dataset_count_stats(dataset: Path) -> Optional[dict[str, Any]]:
    """:func:`summarise_counts` of a dataset's scenes with a count target (None when none has one). The KS
    distance is taken against the target distribution when every scene names the same one and it can be
    read here (a histogram file may not travel with the dataset), else against the drawn targets."""
    from mixcount.counts.targets import parse_count_target
    from mixcount.errors import ConfigError

    rows, rejected = read_dataset(dataset)
    if not rows:
        return None
    texts = {r["distribution"] for r in rows}
    cdf = None
    if len(texts) == 1:
        try:
            cdf = parse_count_target(next(iter(texts))).cdf
        except ConfigError:
            cdf = None
    return {"distributions": sorted(texts), **summarise_counts(rows, rejected, target_cdf=cdf), "rows": rows}


def count_lines(counts: Optional[Mapping[str, Any]], max_listed: int = 10) -> list[str]:
    """The human summary of :func:`dataset_count_stats` (``mixcount stats``)."""
    if not counts or not counts.get("scenes"):
        return []
    pc = counts["per_class"]
    lines = [
        f"count target {', '.join(counts['distributions'])}: {counts['exact']} of {counts['scenes']} scenes kept "
        f"exactly their target, {counts['within_tolerance']} within max(2, 5 %), largest miss {counts['max_abs_miss']}; "
        f"KS distance {counts['ks_distance']} (against the {counts['ks_against']}); median target "
        f"{counts['target_median']:g}, kept {counts['kept_median']:g}",
        "  per bin " + " ".join(f"[{lo},{hi}): {t}/{k}" for lo, hi, t, k in zip(
            counts["bins"]["edges"][:-1], counts["bins"]["edges"][1:], counts["bins"]["target"], counts["bins"]["kept"])
            if t or k) + " (target/kept scenes)",
        f"  per class: {pc['exact']} of {pc['classes']} classes exactly on their drawn count, {pc['within_one']} within "
        f"one, largest offset {pc['max_off']}",
        f"  brought to target: {counts['brought_to_target']} scenes ({counts['surplus_removed']} surplus bodies taken "
        f"out, {counts['spawned_per_target']} spawned per target object); topped up: "
        f"{counts.get('topped_up_scenes', 0)} scenes ({counts.get('topped_up_bodies', 0)} reserve bodies dropped in); "
        f"regenerated: {counts['regenerated']}",
        f"  rest check: {counts.get('rest_fell', 0)} bodies fell when simulated again (took that pose); largest drop "
        f"{counts.get('rest_largest_drop', 0.0)} x size, largest displacement {counts.get('rest_largest_displacement', 0.0)} x size",
    ]
    if counts.get("rest_verified"):
        v = counts["rest_verified"]
        lines.append(f"  verified (the finished pile simulated again, whole): {v['scenes_with_a_fall']} of {v['scenes']} "
                     f"scenes with a body falling more than the tolerance ({v['fell']} bodies, "
                     f"{v['fell_over_half_size']} more than half their size); largest drop {v['largest_drop_x_size']} x size")
    if counts["imbalance"]:
        kept = [r["kept"] for r in counts["imbalance"]]
        drawn = [r["drawn"] for r in counts["imbalance"]]
        lines.append(f"  imbalance (largest / smallest class): drawn {min(drawn):.2f}-{max(drawn):.2f}, "
                     f"kept {min(kept):.2f}-{max(kept):.2f} over {len(kept)} scenes")
    for r in counts["regenerated_scenes"][:max_listed]:
        lines.append(f"  regenerated {r['scene_id']} (seed {r['seed']}): {r['why']}")
    for r in counts["too_small"][:max_listed]:
        lines.append(f"  {r['scene_id']}: objects too small in the frame (median visible pixels < "
                     f"{r['min_object_px']:g}): about {r['resolution_needed']} px per side needed")
    return lines
