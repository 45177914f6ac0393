"""``mixcount verify OUT``: check a composed dataset against the record of its files (docs/faults.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from mixcount.commands.common import RichProgress, console, json_option, result
from mixcount.errors import DatasetError

PRINTED_LINES = 50  # problem lines printed on stderr; the report of --json lists all


def verify_cmd(
    out_dir: Path = typer.Argument(..., help="Compose output folder (OUT/scenes/<scene_id>/...)."),
    quick: bool = typer.Option(False, "--quick", help="Compare sizes and hash only files whose modification "
                               "time changed (what compose checks), instead of hashing every file."),
    json_out: bool = json_option("the report (every problem)"),
) -> None:
    """Check every finished scene against the size and SHA-256 recorded for each of its files, and the
    merged files against the scenes. Lists missing, changed and extra files; exits 1 when any are found."""
    from mixcount.dataset.verify import verify_dataset

    if not (out_dir / "scenes").is_dir():
        raise DatasetError(f"{out_dir} holds no scenes/ folder: nothing to verify")
    report = verify_dataset(out_dir.resolve(), deep=not quick, progress=RichProgress())
    for line in report.lines(limit=PRINTED_LINES):
        console.print(line, highlight=False, markup=False, soft_wrap=True)
    damaged = sum(c.damaged for c in report.scene_problems)
    verdict = ("whole" if not report.problems else
               f"{report.problems} problem(s), {damaged} damaged scene(s): run the same `mixcount compose` "
               "to set damaged scenes aside and render them again, `mixcount merge` for the merged files")
    result(f"verified {report.scenes} finished scene(s) and the merged files in {report.seconds:.1f} s "
           f"({report.hashed_bytes / 1e6:.1f} MB hashed): {verdict}", report.to_dict(), json_out)
    if report.problems:
        raise typer.Exit(1)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("verify")(verify_cmd)
