"""CLI: `mixcount demo-library [PATH]`: write the generated demo object library (DTC layout)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from mixcount.commands.common import json_option, result, state


def demo_library_cmd(
    ctx: typer.Context,
    path: Path = typer.Argument(Path("catalog/demo"), help="Folder to write the library into."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Generator seed [default: demo.seed]; same seed, same bytes."),
    n: Optional[int] = typer.Option(None, "--n", help="Number of ordinary objects [default: demo.n_objects, 0 = all 58]."),
    json_out: bool = json_option("the ground truth's counts"),
) -> None:
    """Generate the demo library: everyday objects, containers and curation traps, plus ground_truth.json."""
    from mixcount.curation.finding.ground_truth import TRAP_KINDS
    from mixcount.demo.library import generate_demo_library

    demo = state(ctx).config(values={"demo.seed": seed, "demo.n_objects": n}).demo
    t0 = time.perf_counter()
    truth = generate_demo_library(path, seed=demo.seed, n_objects=demo.n_objects or None)
    exp = truth["expected"]
    result(
        f"demo library in {path}: {exp['total']} folders ({exp['active']} good, {exp['broken']} broken) in "
        f"{len(truth['categories'])} categories; traps: "
        + ", ".join(f"{len(truth.get(key, []))} {kind}" for key, kind in TRAP_KINDS)
        + f", {len(truth.get('mesh_quality', []))} mesh_quality [{time.perf_counter() - t0:.1f} s]",
        {"path": str(path), **exp, "categories": truth["categories"]},
        json_out,
    )


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("demo-library")(demo_library_cmd)
