"""``mixcount compose`` (plan, USD stages, render), ``mixcount merge`` (dataset files from the finished
scenes) and ``mixcount catalog ingest-env`` / ``ingest-materials``.

``compose_cmd`` is thin: its options become one :class:`~mixcount.config.Config`, then
:class:`mixcount.run.compose_entry.ComposeJob` (shared with :func:`mixcount.api.compose`) checks, plans or
runs, and this module prints: the dry run's plan, ``--stage-only``'s ``OUT/scenes/<scene_id>/scene.usda``
files, the run's summary.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import typer

from mixcount.commands.common import RichProgress, console, json_option, out, result, state
from mixcount.config import Config
from mixcount.errors import CompositionError, PartialFailure


def summarise(spec: Any) -> dict[str, Any]:
    """What a dry run prints for one scene."""
    return {
        "scene_id": spec.scene_id, "seed": spec.seed, "split": spec.split, "n_counted": spec.n_counted,
        "classes": [
            {"class_index": c.class_index, "object_id": c.object_id, "name": c.name, "category": c.category,
             "count": c.count, "size_m": c.target_size_m, "size_real_m": round(c.target_size_m / spec.scale, 4),
             "qualifier": c.size_qualifier, "construction": c.construction, "caption": c.captions.concise}
            for c in spec.classes
        ],
        "container": None if spec.container is None else spec.asset(spec.container.object_id).name,
        "distractors": [spec.asset(d.object_id).name for d in spec.distractors],
        "floor": f"{spec.floor.shape} / {spec.floor.material.name}",
        "environment": spec.environment.kind,
        "environment_map": Path(spec.environment.path).name if spec.environment.path else None,
    }


def write_stages(specs: list[Any], out_dir: Path, catalog: Any, *, progress: bool = True) -> list[Path]:
    from rich.progress import Progress

    from mixcount.usd.stage import write_stage

    paths: list[Path] = []
    with Progress(console=console, transient=True, disable=not progress) as bar:
        task = bar.add_task("writing USD stages", total=len(specs))
        for spec in specs:
            paths.append(write_stage(spec, out_dir, catalog))
            bar.advance(task)
    return paths


def _print_notes(notes: list[str]) -> None:
    """What the run will say at its start (objects never captioned or rendered, seeds passed over), once, on
    stderr: before a dry run's plan or ``--stage-only``'s stages."""
    for line in notes:
        console.print(f"[yellow]note:[/] {line}", highlight=False, soft_wrap=True)


def _print_dry_run(specs: list[Any]) -> None:
    """The readable plan of a dry run, on stdout."""
    from rich.table import Table

    table = Table(title=f"{len(specs)} planned scene(s)")
    for col in ("scene", "n", "classes (count x size m, construction)", "container", "distr."):
        table.add_column(col)
    for spec in specs:
        cls = "\n".join(
            f"{c.captions.concise!s} : {c.count} x {c.target_size_m:.2f} ({c.construction})" for c in spec.classes
        )
        cont = "-" if spec.container is None else spec.asset(spec.container.object_id).name
        table.add_row(spec.scene_id, str(spec.n_counted), cls, cont, str(len(spec.distractors)))
    out.print(table)


def _compose_lines(summary: Any, out_dir: Path, *, merge: bool) -> list[str]:
    """The readable summary of a compose run: counts, then where the preview and annotations are."""
    repaired = f", {len(summary.damaged)} damaged set aside and rendered again" if summary.damaged else ""
    lines = [f"wrote {summary.written - summary.skipped} new scene(s) ({summary.skipped} already there, {summary.failed} failed, "
             f"{summary.empty + summary.rejected} regenerated{repaired}) in {summary.seconds:.0f} s into {out_dir}"]
    written = [str(o.get("scene_id")) for o in (summary.outcomes or []) if o.get("status") == "written"]
    if written:  # the ids, to hold against the dry run's plan
        lines.append("new scenes: " + ", ".join(written[:8]) + (f" and {len(written) - 8} more" if len(written) > 8 else ""))
    from mixcount.run.object_pixels import summary_lines

    lines += summary_lines(getattr(summary, "object_px", None))  # pixels per counted object against the floor
    if summary.failures:  # what failed and where each failure is explained
        from collections import Counter

        causes = Counter(str(f.get("cause", "unknown")) for f in summary.failures)
        lines.append("failed scenes by cause: " + ", ".join(f"{c} {k}" for c, k in causes.most_common())
                     + f" (seeds, signals and kept logs: {out_dir / 'logs' / 'failures.jsonl'})")
    outputs = summary.outputs or {}
    if outputs.get("preview"):
        lines.append(f"preview: {outputs['preview']}")
    annotations = outputs.get("annotations") or {}
    if isinstance(annotations, dict):
        lines.extend(f"annotations ({split}): {path}" for split, path in sorted(annotations.items()))
    elif annotations:
        lines.append(f"annotations: {annotations}")
    if not outputs:
        lines.append(f"annotations and preview of {out_dir} unchanged (no new scene)" if merge else
                     f"not merged (--no-merge): `mixcount merge {out_dir}` writes the annotations and preview")
    return lines


def _views_lines(config: Config) -> list[str]:
    """What ``--views`` / ``--trajectory orbit`` added to every scene (nothing without them)."""
    from mixcount.worker.contract import MoreViews

    more = MoreViews.from_config(config.rerender, config.scene)
    if more is None:
        return []
    added = [f"{more.plan.new_views} by the paper's camera rule"] if more.plan.new_views else []
    if more.plan.trajectory == "orbit":
        added.append(f"{more.plan.frames} along an orbit")
    return [f"views: each scene's own camera(s) and {' and '.join(added)}, rendered in its one worker pass "
            f"(annotation rule {more.rule})"]


def absolute_counts(counts: Optional[str]) -> Optional[str]:
    """``--counts`` with a histogram's relative path made absolute (the workers and the recorded config
    read it from any folder); None stays None (the config's value)."""
    if counts is None:
        return None
    head, sep, rest = counts.partition(",")
    kind, colon, value = head.partition(":")
    if kind in ("histogram", "hist") and colon and not Path(value).is_absolute():
        head = f"{kind}:{Path(value).resolve()}"
    return head + sep + rest


def compose_cmd(
    ctx: typer.Context,
    n: int = typer.Option(1, "--n", min=1, help="Number of scenes."),
    out_dir: Path = typer.Option(Path("out"), "--out", help="Output folder (scenes/<scene_id>/...)."),
    split: Optional[str] = typer.Option(None, "--split", help="Split to draw objects from: train, val, test, test_objects or test_categories (default: config compose.split)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Seed of the first scene (default: config compose.seed)."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print classes, counts and sizes; write nothing."),
    stage_only: bool = typer.Option(False, "--stage-only", help="Write scene.usda stages, no rendering."),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="bpy worker processes (default: config compose.workers)."),
    resolution: Optional[int] = typer.Option(None, "--resolution", min=16, help="Image side in pixels (compose.resolution)."),
    samples: Optional[int] = typer.Option(None, "--samples", min=1, help="Cycles samples of the RGB render (compose.samples)."),
    config_file: Optional[Path] = typer.Option(None, "--config", help="Extra config file (after the global --config files)."),
    executor_kind: str = typer.Option("local", "--executor", help="local (bpy worker processes here) or ray (one task per scene on a Ray cluster)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address host:port for --executor ray (default: start a local cluster)."),
    passes: Optional[str] = typer.Option(None, "--passes", help="Comma list of passes written besides rgb.png: instance, class, depth, normal (default: config compose.passes, all four)."),
    no_merge: bool = typer.Option(False, "--no-merge", help="Skip the dataset merge at the end (run `mixcount merge OUT` later)."),
    package_assets: bool = typer.Option(False, "--package-assets", help="At the end, copy the assets the stages use into OUT/assets/ (as `mixcount package OUT`): the dataset then opens and re-renders anywhere."),
    mixed_settings: bool = typer.Option(False, "--mixed-settings", help="Add scenes to an OUT whose scenes were composed with other settings (resolution, samples, scene rules, catalog): recorded as another variant in OUT/settings.json; without it such a run is refused."),
    views: Optional[int] = typer.Option(None, "--views", min=0, help="New cameras per scene by the paper's camera rule around its settled pile, rendered in the same worker pass as its own (rerender.new_views; default 0)."),
    trajectory: Optional[str] = typer.Option(None, "--trajectory", help="none or orbit: --frames more cameras on a circle around each pile (rerender.trajectory)."),
    frames: Optional[int] = typer.Option(None, "--frames", min=1, help="Cameras along the orbit (rerender.frames)."),
    rule: Optional[str] = typer.Option(None, "--rule", help="How the views are annotated: all_cameras (the paper's) or per_view (rerender.annotation_rule)."),
    counts: Optional[str] = typer.Option(None, "--counts", help="Visible counted objects per image (scene.count_target): paper (spawned n ~ scene.n_objects, the default), uniform:A-B or histogram:PATH ('count weight' lines, or a COCO instances / FSC-147 annotation JSON: a COCO file's per-category counts also give the class split, matched to the classes by object size), optionally followed by ,imbalance:R1-R2 (largest / smallest class per scene); docs/scene.md."),
    device: Optional[str] = typer.Option(None, "--device", help="Where Cycles renders: cpu (the default), gpu (CUDA / OptiX / HIP / oneAPI; exit 2 before anything is written when none is usable) or auto (a GPU when one works, else the CPU, said once); compose.device, docs/faults.md."),
    json_out: bool = json_option("the plan (--dry-run), the stages (--stage-only) or the run's summary"),
) -> None:
    """Compose counting scenes: sample them by the paper's rules, write USD stages, render."""
    st = state(ctx)
    # --config, --split, --seed, --workers, --resolution and --samples are config overrides: applied in
    # the one build of the configuration, so dataset.json records what was run.
    cfg = st.config(files=[config_file] if config_file is not None else [], values={
        "compose.split": split, "compose.seed": seed, "compose.workers": workers,
        "compose.resolution": resolution, "compose.samples": samples,
        "compose.passes": None if passes is None else [p.strip() for p in passes.split(",") if p.strip()],
        "compose.merge": False if no_merge else None, "scene.count_target": absolute_counts(counts),
        "rerender.new_views": views, "rerender.trajectory": trajectory, "rerender.frames": frames,
        "rerender.annotation_rule": rule, "compose.device": device})
    from mixcount.run.compose_entry import ComposeJob

    job = ComposeJob.checked(cfg, n=n, out_dir=out_dir)  # a bad count target stops here, before anything is written
    catalog = st.catalog()
    if dry_run or stage_only:
        plan = job.plan(catalog)
        _print_notes(plan.notes)
        if stage_only:
            paths = write_stages(plan.specs, out_dir, catalog)
            result(f"wrote {len(paths)} stage(s) under {out_dir / 'scenes'}", {"stages": [str(p) for p in paths]},
                   json_out)
        elif json_out:
            result("", [summarise(s) for s in plan.specs], True)
        else:
            _print_dry_run(plan.specs)
        return
    summary = job.run(catalog, executor_kind=executor_kind, workers=workers, address=address,
                      progress=RichProgress(), mixed_settings=mixed_settings)
    packaged = None
    if package_assets:  # each asset checked against the catalog's libraries first (mixcount.dataset.sources)
        from mixcount.dataset.package import package_with_catalog

        packaged = package_with_catalog(out_dir, catalog, cfg)
        for line in packaged.lines():
            console.print(line, highlight=False, soft_wrap=True, markup=False)
        console.print(f"packaged {len(packaged.copied)} asset entr(ies) into {out_dir / 'assets'} ({packaged.bytes:,} bytes "
                      f"written, {len(packaged.refused)} refused; listed in {out_dir / 'package.json'})", highlight=False)
    result(_compose_lines(summary, out_dir, merge=cfg.compose.merge) + _views_lines(cfg), {k: v for k, v in summary.to_dict().items() if k != "outcomes"},
           json_out)
    _fail_on_failed_seeds(st, ctx, summary, n, out_dir)
    if packaged is not None:
        packaged.raise_if_refused(out_dir)


def _fail_on_failed_seeds(st: Any, ctx: typer.Context, summary: Any, n: int, out_dir: Path) -> None:
    """Exit 3 (:class:`PartialFailure`) when a seed failed, also when other seeds made up the count: one
    line per failed scene, the way to compose each failed seed again; exit 2 when fewer than ``n`` scenes
    were written without a failed seed to name."""
    failures = list(summary.failures or [])
    if failures:
        failed = [(f"{f.get('scene_id')} (seed {f.get('seed')})", f"[{f.get('cause', 'unknown')}] {f.get('error') or ''}")
                  for f in failures]
        seeds = [str(f.get("seed")) for f in failures]
        one = st.rerun(ctx=ctx, drop=("n", "seed", "dry_run", "stage_only"))
        again = (f"{one} --n 1 --seed {seeds[0]}" if len(seeds) == 1 else
                 f"for s in {' '.join(seeds)}; do {one} --n 1 --seed $s; done")
        short = f", only {summary.written} of {n} written" if summary.written < n else ""
        raise PartialFailure("scenes", failed, summary.written - summary.skipped + len(failures),
                             log=str(out_dir / "logs" / "failures.jsonl"),
                             headline=f"compose: {len(failures)} seed(s) failed{short}", rerun=again)
    if summary.written < n:
        raise CompositionError(f"only {summary.written} of {n} scenes could be written (see failures above)")


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("compose")(compose_cmd)

    app.command("merge")(merge_cmd)
    catalog_app.command("ingest-env")(ingest_env_cmd)
    catalog_app.command("ingest-materials")(ingest_materials_cmd)


ALLOW_ROOT_HELP = ("A folder outside the one named that its links may lead into (repeatable; adds to "
                   "[ingest] extra_roots). Without it such a link is refused and said.")


def _assets_result(kind: str, summary: Any, json_out: bool, st: Any, ctx: typer.Context) -> None:
    """What ``ingest-env`` / ``ingest-materials`` print: the summary, then (exit 3, :class:`PartialFailure`)
    one line per file broken (recorded, never drawn) or refused (a link out of the library, not read)."""
    result(f"{kind}: {summary.new} new, {summary.unchanged} unchanged, {len(summary.broken)} broken "
           f"(never drawn), {len(summary.refused)} refused (outside the library), {len(summary.skipped)} skipped",
           summary.to_dict(), json_out)
    failed = [(p, f"broken: {r}") for p, r in summary.broken] + [(p, f"refused: {r}") for p, r in summary.refused]
    if failed:
        total = summary.new + summary.unchanged + len(summary.refused)
        raise PartialFailure(kind, failed, total, rerun=st.rerun(ctx=ctx),
                             headline=f"{kind}: {len(summary.broken)} broken (recorded, never drawn: replace them), "
                                      f"{len(summary.refused)} refused (outside the library)")


def ingest_env_cmd(ctx: typer.Context, paths: list[Path] = typer.Argument(..., help="HDR/EXR files or folders."),
                   allow_root: list[Path] = typer.Option([], "--allow-root", help=ALLOW_ROOT_HELP),
                   json_out: bool = json_option("the summary")) -> None:
    """Add HDR/EXR environment maps to the catalog (sampled uniformly per scene); each is decoded whole
    first, and one that does not decode is recorded broken and never drawn."""
    from mixcount.catalog.environments import ingest_environments

    _ingest_assets(ctx, "environments", ingest_environments, paths, allow_root, json_out)


def ingest_materials_cmd(ctx: typer.Context, paths: list[Path] = typer.Argument(..., help="Folders of PBR texture sets."),
                         allow_root: list[Path] = typer.Option([], "--allow-root", help=ALLOW_ROOT_HELP),
                         json_out: bool = json_option("the summary")) -> None:
    """Add PBR texture sets (base colour, roughness, normal, ...) for floors; every map is decoded whole
    first, and a set with one that does not decode is recorded broken and never drawn."""
    from mixcount.catalog.environments import ingest_materials

    _ingest_assets(ctx, "materials", ingest_materials, paths, allow_root, json_out)


def _ingest_assets(ctx: typer.Context, what: str, ingest: Any, paths: list[Path], allow_root: list[Path],
                   json_out: bool) -> None:
    """``ingest-env`` / ``ingest-materials``: ``ingest`` (the catalog step) under the library boundary
    (``[ingest] extra_roots`` and ``--allow-root``) and the pixel limit, then the result and its exit code."""
    st = state(ctx)
    ing = st.config().ingest
    catalog = st.catalog(create=True)
    try:
        summary = ingest(catalog, paths, max_pixels=ing.max_image_pixels,
                         extra_roots=[*ing.extra_roots, *map(str, allow_root)])
    finally:
        catalog.close()  # the writer lock goes with it
    _assets_result(what, summary, json_out, st, ctx)


def merge_cmd(
    ctx: typer.Context,
    out_dir: Path = typer.Argument(Path("out"), help="Compose output folder (OUT/scenes/<scene_id>/...)."),
    json_out: bool = json_option("the merge's result"),
) -> None:
    """Merge the finished scenes of OUT into annotations/instances_<split>.json, dataset.json and
    preview.png (one streaming pass; unchanged scenes' summaries come from the merge index)."""
    import time

    from mixcount.dataset.merge import finalize_dataset

    if not (out_dir / "scenes").is_dir():
        raise CompositionError(f"{out_dir} holds no scenes/ folder: nothing to merge")
    cfg = state(ctx).config()
    t0 = time.perf_counter()
    res = finalize_dataset(out_dir.resolve(), config=cfg.to_dict(), config_hash=cfg.hash,
                           preview_scenes=cfg.compose.preview_scenes)
    for line in res.get("damaged", []):
        console.print(f"[yellow]damaged scene left out:[/] {line}", highlight=False)
    result(f"merged in {time.perf_counter() - t0:.1f} s: {res['dataset']}", res, json_out)
    if res.get("damaged"):
        console.print(f"{len(res['damaged'])} damaged scene(s) left out of the merge: run the same `mixcount "
                      "compose` to render them again (`mixcount verify` lists every problem)", highlight=False)
        raise typer.Exit(1)
