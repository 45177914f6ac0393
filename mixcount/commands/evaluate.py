"""CLI: `mixcount evaluate` (counting metrics) and `mixcount stats` (dataset statistics and plots)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

import typer

from mixcount.commands.common import console, json_option, out, result


def _fmt(value: float | None, pct: bool = False) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.1f}%" if pct else f"{value:.3f}"


def evaluate_cmd(
    gt: Path = typer.Option(..., "--gt", help="COCO ground truth (OUT/annotations/instances_test.json) or a dataset folder."),
    pred: Path = typer.Option(
        ..., "--pred",
        help="Prediction JSON: rows of image_id, category_id, count|boxes|points, or COCO detection results "
             "(image_id, category_id, bbox, score).",
    ),
    split: str = typer.Option("test", "--split", help="Split to read when --gt is a dataset folder (test, or "
                              "test_objects / test_categories when catalog split wrote them)."),
    by: Optional[str] = typer.Option(
        None, "--by", help="Group by a field of the prediction rows (prompt, tier) or of GT categories/images."
    ),
    counted_only: bool = typer.Option(
        False, "--counted-only", help="Drop pairs whose category is only present as a distractor in the image."
    ),
    score_absent: bool = typer.Option(
        False, "--score-absent", help="Score rows for known categories absent from an image as y = 0 pairs."
    ),
    json_out: bool = json_option("the scores (one JSON object) instead of a table"),
    score_threshold: Optional[float] = typer.Option(
        None, "--score-threshold",
        help="COCO detection results only: a detection counts when its score is above this (default 0.5).",
    ),
) -> None:
    """Score predicted counts: MAE, RMSE, NAE and Acc10% per (image, category), the MixCount protocol."""
    from mixcount.evaluate.detections import load_prediction_file
    from mixcount.evaluate.metrics import evaluate, load_ground_truth

    truth = load_ground_truth(gt, split=split)
    rows = load_prediction_file(pred, score_threshold)
    scores = evaluate(truth, rows, by=by, counted_only=counted_only, score_absent=score_absent, pred_source=str(pred))
    if json_out:
        payload: dict[str, Any] = {"gt": truth.source, "pred": str(pred), **scores.as_dict()}
        typer.echo(json.dumps(payload, sort_keys=True))  # not rich: JSON could look like markup
    else:
        _print_table(scores, truth.source, str(pred))
    o = scores.overall
    if o.missing:
        console.print(
            f"[yellow]{o.missing} ground-truth pair(s) had no prediction and were scored as 0[/], e.g. "
            + ", ".join(f"(image {i}, category {c})" for i, c in scores.missing_examples),
            highlight=False,
        )
    if o.extra:
        console.print(
            f"[yellow]{o.extra} prediction row(s) for pairs not in the ground truth were not scored[/], e.g. "
            + ", ".join(f"(image {i}, category {c})" for i, c in scores.extra_examples),
            highlight=False,
        )


def _print_table(result: Any, gt: str, pred: str) -> None:
    from rich.table import Table

    table = Table(title=f"counting metrics: {Path(pred).name} vs {Path(gt).name}")
    first = result.by or ""
    for col in (first, "pairs", "MAE", "RMSE", "NAE", "Acc10%", "missing", "extra", "y=0"):
        table.add_column(col, justify="left" if col == first else "right")

    def add(name: str, s: Any, style: str | None = None) -> None:
        table.add_row(
            name, str(s.pairs), _fmt(s.mae), _fmt(s.rmse), _fmt(s.nae), _fmt(s.acc10, pct=True), str(s.missing),
            str(s.extra), str(s.zero_pairs), style=style,
        )

    for name, s in result.groups.items():
        add(name, s)
    add("all", result.overall, style="bold")
    out.print(table)


def stats_cmd(
    dataset: Path = typer.Argument(..., help="Dataset folder written by `mixcount compose` (OUT)."),
    plots_dir: Optional[Path] = typer.Option(None, "--plots-dir", help="Where PNGs and stats.json go [default: OUT/stats]."),
    plots: bool = typer.Option(True, "--plots/--no-plots", help="Write the PNG plots."),
    json_out: bool = json_option("stats.json"),
) -> None:
    """Dataset statistics: objects and classes per scene, class imbalance, visibility, splits, captions, and
    kept vs spawned per scene (drop reasons, classes left with no visible instance) from scenes/*/metadata.json."""
    from rich.table import Table

    from mixcount.evaluate.stats import compute_stats, per_split_table, summary_lines, write_stats

    stats = compute_stats(dataset)
    target = plots_dir if plots_dir is not None else Path(dataset) / "stats"
    json_path = write_stats(stats, target / "stats.json")
    if plots:
        from mixcount.evaluate.plots import write_plots

        paths = write_plots(stats, target)
        if stats.get("count_target"):  # issue 37: the target against the kept counts
            from mixcount.evaluate.count_stats import plot_counts

            paths.append(plot_counts(stats["count_target"], stats["count_target"]["rows"], target / "count_target.png"))
        console.print(f"wrote {len(paths)} plots and {json_path.name} to {target}", highlight=False)
    else:
        console.print(f"wrote {json_path}", highlight=False)
    table = Table(title=f"dataset {dataset}")
    for col in ("split", "images", "scenes", "objects", "distractors", "classes"):
        table.add_column(col, justify="left" if col == "split" else "right")
    for row in per_split_table(stats):
        table.add_row(*(str(x) for x in row))
    (console if json_out else out).print(table)
    result(summary_lines(stats), stats, json_out)


def baseline_cmd(
    gt: Path = typer.Option(..., "--gt", help="COCO ground truth to predict for, or a dataset folder."),
    out_path: Path = typer.Option(..., "--out", help="Prediction JSON to write."),
    kind: str = typer.Option("mean", "--kind", help="mean (mean count of --reference) or perfect (the GT itself)."),
    split: str = typer.Option("test", "--split", help="Split to read when --gt is a dataset folder (test, or "
                              "test_objects / test_categories when catalog split wrote them)."),
    reference: Optional[Path] = typer.Option(
        None, "--reference",
        help="Where the mean baseline's mean count comes from: a dataset folder (its --reference-split is read) "
             "or a COCO file; never the split being evaluated (that would leak the answer).",
    ),
    reference_split: str = typer.Option("train", "--reference-split", help="Split read when --reference is a dataset folder."),
    json_out: bool = json_option("what was written"),
) -> None:
    """Write a baseline prediction file: the mean-count floor, or the perfect oracle (checks the pipeline)."""
    from mixcount.errors import EvaluationError
    from mixcount.evaluate.metrics import load_ground_truth, load_reference, mean_predictions, perfect_predictions

    if kind not in ("mean", "perfect"):
        raise EvaluationError(f"unknown baseline {kind!r} (mean | perfect)")
    truth = load_ground_truth(gt, split=split)
    ref_source: str | None = None
    if kind == "perfect":
        rows = perfect_predictions(truth, prompt="oracle")
    else:
        ref = None
        if reference is not None:
            ref = load_reference(reference, split=reference_split, evaluated=truth)
            ref_source = ref.source
        else:
            console.print(f"[yellow]warning:[/] no --reference: the mean count is taken from {truth.source}, the "
                          "split being evaluated, so the baseline knows the answer; give --reference DATASET "
                          "(its train split) for a fair floor", highlight=False, soft_wrap=True)
        rows = mean_predictions(truth, ref, prompt="mean")
    doc = {"baseline": kind, "gt": truth.source, "reference": ref_source, "predictions": rows}
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    mean = f" (mean count {rows[0]['count']:.2f} of {ref_source or truth.source})" if kind == "mean" and rows else ""
    result(f"wrote {len(rows)} {kind} predictions for {truth.source} to {out_path}{mean}",
           {"out": str(out_path), "baseline": kind, "gt": truth.source, "reference": ref_source, "rows": len(rows)},
           json_out)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("evaluate")(evaluate_cmd)
    app.command("stats")(stats_cmd)
    app.command("baseline")(baseline_cmd)
