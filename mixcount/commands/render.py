"""``mixcount render DATASET --out NEW``: finished scenes rendered again from their settled stages, no
physics (mixcount/run/rerender.py): other resolution / samples / denoiser, more views, an orbit."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, Optional

import typer

from mixcount.commands.common import console, json_option, result, state
from mixcount.errors import PartialFailure


def _lines(summary: Any) -> list[str]:
    written = [s for s in summary.scenes if s["status"] == "written"]
    views = sum(int(s["views"]) for s in written)
    dev = summary.device
    lines = [f"rendered {len(written)} of {len(summary.scenes)} scene(s) again ({views} view(s)) in "
             f"{summary.seconds:.1f} s into {summary.out} on {dev['used']} ({', '.join(dev['devices']) or dev['backend']})"]
    lines += [f"{s['scene_id']}: {s['status']}" for s in summary.scenes if s["status"] != "written"]
    annotations = (summary.merged or {}).get("annotations") or {}
    if isinstance(annotations, dict):
        lines.extend(f"annotations ({split}): {path}" for split, path in sorted(annotations.items()))
    return lines


def render_cmd(
    ctx: typer.Context,
    dataset: Path = typer.Argument(..., help="A composed dataset (DATASET/scenes/<scene_id>/settled.usda)."),
    out_dir: Path = typer.Option(..., "--out", help="New dataset folder (must not exist or be empty)."),
    resolution: Optional[int] = typer.Option(None, "--resolution", min=16, help="Image side in pixels (rerender.resolution; default: each scene's own)."),
    samples: Optional[int] = typer.Option(None, "--samples", min=1, help="Cycles samples of the RGB render (rerender.samples; default: each scene's own)."),
    views: Optional[int] = typer.Option(None, "--views", min=0, help="New cameras by the paper's camera rule around each settled pile (rerender.new_views)."),
    trajectory: Optional[str] = typer.Option(None, "--trajectory", help="none or orbit (rerender.trajectory)."),
    frames: Optional[int] = typer.Option(None, "--frames", min=1, help="Cameras along the orbit (rerender.frames)."),
    rule: Optional[str] = typer.Option(None, "--rule", help="all_cameras (the paper's) or per_view (rerender.annotation_rule)."),
    device: Optional[str] = typer.Option(None, "--device", help="cpu, gpu or auto (rerender.device)."),
    passes: Optional[str] = typer.Option(None, "--passes", help="Comma list of passes besides rgb.png (compose.passes)."),
    oracle: bool = typer.Option(False, "--oracle", help="Also run the one-render-per-object reference per view (slow; oracle_masks*.npz)."),
    no_merge: bool = typer.Option(False, "--no-merge", help="Skip the merge at the end."),
    scenes: list[str] = typer.Option([], "--scene", help="Only this scene id (repeatable; what a run with "
                                     "failed scenes says to rerun)."),
    json_out: bool = json_option("the run's summary"),
) -> None:
    """Render the finished scenes of DATASET again into a new dataset: no physics, no re-placement. Exits 3
    when a scene could not be rendered again (one line each, and the command for only those)."""
    from mixcount.run.rerender import rerender_dataset
    from mixcount.worker.client import BlenderWorker

    cfg = state(ctx).config(values={
        "rerender.resolution": resolution, "rerender.samples": samples, "rerender.new_views": views,
        "rerender.trajectory": trajectory, "rerender.frames": frames, "rerender.annotation_rule": rule,
        "rerender.device": device,
        "compose.passes": None if passes is None else [p.strip() for p in passes.split(",") if p.strip()]})
    worker = BlenderWorker(name="rerender", log_dir=Path(tempfile.gettempdir()),
                           cpu_threads=cfg.compose.render_threads)  # the threads its scenes render with
    try:
        summary = rerender_dataset(dataset, out_dir, cfg, worker, oracle=oracle, merge=not no_merge,
                                   progress=lambda k, n: console.print(f"scene {k}/{n}", highlight=False),
                                   only=scenes or None)
    finally:
        worker.close()
    result(_lines(summary), summary.to_dict(), json_out)
    failed = [(str(s["scene_id"]), f"status {s['status']}") for s in summary.scenes if s["status"] != "written"]
    if failed:
        again = Path(f"{out_dir}-again")
        rerun = state(ctx).rerun("--out", str(again), *[w for sid, _ in failed for w in ("--scene", sid)],
                                 ctx=ctx, drop=("out_dir", "scenes"))
        raise PartialFailure("scenes rendered again", failed, len(summary.scenes),
                             rerun=f"{rerun} (a new folder: the re-render never writes into a used one)")


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("render")(render_cmd)
