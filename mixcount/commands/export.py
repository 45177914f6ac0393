"""``mixcount export``: a composed dataset in the layout a counting codebase trains on (docs/export.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mixcount.commands.common import RichProgress, json_option, result


def export_cmd(
    dataset: Path = typer.Argument(..., help="Dataset folder written by `mixcount compose --out` (read only)."),
    fmt: str = typer.Option(
        ..., "--format", "-f",
        help="fsc147 (LOCA, DAVE, GeCo, CounTR; PairTally fields) | countgd (ODVG + COCO exemplars) | "
             "hf (Hugging Face Parquet + dataset card) | fiftyone (COCO with masks and attributes).",
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Export folder (created; a rerun resumes and updates it)."),
    split: Optional[str] = typer.Option(None, "--split", help="Export only this split (default: every split)."),
    caption_tier: str = typer.Option(
        "concise", "--caption-tier", help="Class text written for each class: short | concise | detailed."
    ),
    json_out: bool = json_option("the export's manifest"),
) -> None:
    """Export a composed dataset for training: FSC-147, CountGD, Hugging Face or FiftyOne, with ATTRIBUTION."""
    from mixcount.export import export_dataset

    manifest = export_dataset(dataset, fmt, out, split=split, tier=caption_tier, progress=RichProgress())
    figures = ", ".join(f"{k}: {_figure(v)}" for k, v in manifest["figures"].items())
    files = manifest["files"]
    result(f"{fmt} export of {dataset} in {out}: {figures} "
           f"({files['written']} file(s) written, {files['up_to_date']} up to date; ATTRIBUTION.md included)",
           manifest, json_out)


def _figure(value: object) -> str:
    """One figure of the manifest as a person reads it: no Python dict, floats to 3 significant digits."""
    if isinstance(value, dict):
        return "(" + ", ".join(f"{k} {_figure(v)}" for k, v in value.items()) + ")" if value else "none"
    if isinstance(value, (list, tuple)):
        return ", ".join(_figure(v) for v in value) or "none"
    if isinstance(value, float):
        return f"{value:.3g}"
    return "-" if value is None else str(value)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("export")(export_cmd)
