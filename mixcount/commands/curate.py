"""CLI: `catalog render`, `catalog filter`, `catalog sheet`, `catalog review import`."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from mixcount.commands.common import RichProgress, console, failure_log, json_option, result, state
from mixcount.errors import PartialFailure

review_app = typer.Typer(help="Apply a person's accept/reject decisions from the HTML review page.",
                         no_args_is_help=True)


def render_cmd(
    ctx: typer.Context,
    force: bool = typer.Option(False, "--force", help="Render again even when the stored render is current."),
    include_excluded: bool = typer.Option(False, "--include-excluded", help="Also render excluded objects."),
    ids: list[int] = typer.Option([], "--id", help="Only these object ids (repeatable)."),
    only_failed: bool = typer.Option(False, "--only-failed", help="Only the objects whose last render failed "
                                     "(what a run with failures says to rerun)."),
    executor: str = typer.Option("local", "--executor", help="local (processes here) or ray (the per-object "
                                 "work as Ray tasks; the catalog is written here: docs/ray.md)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address host:port for --executor "
                                          "ray (default: start a local cluster)."),
    json_out: bool = json_option("the summary"),
) -> None:
    """Canonical white-background renders of active objects (bpy worker processes; resumable). Exits 3
    when any object failed to render: one line each, the full errors in the catalog's logs/ folder."""
    from mixcount.curation.renders import render_catalog

    st = state(ctx)
    catalog = st.catalog(write=True)
    try:
        if only_failed:
            ids = [i for i in failed_render_ids(catalog) if not ids or i in ids]
            if not ids:
                result("render: no object has a failed render", {"objects": 0, "failed": 0}, json_out)
                return
        from mixcount.run.catalog_tasks import catalog_executor

        with catalog_executor(executor, address):
            summary = render_catalog(catalog, st.config().canonical_render, object_ids=ids or None,
                                     include_excluded=include_excluded, force=force, progress=RichProgress(),
                                     palette=st.config().palette)
        failed = [(f"#{f['id']} {f['name']}", str(f["error"])) for f in summary.failures]
        log = failure_log(catalog, "catalog-render", failed) if failed else None
    finally:
        catalog.close()
    result(f"render: {summary.objects} objects, {summary.rendered} rendered, {summary.skipped} up to date, "
           f"{summary.failed} failed", summary.as_dict(), json_out)
    if failed:
        raise PartialFailure("canonical renders", failed, summary.rendered + summary.failed,
                             rerun=st.rerun("--only-failed", ctx=ctx, drop=("force", "only_failed")),
                             log=str(log))


def failed_render_ids(catalog) -> list[int]:  # type: ignore[no-untyped-def]
    """Ids of the objects whose stored canonical render (any view) is a failure."""
    from sqlalchemy import select

    from mixcount.catalog.models import Render

    with catalog.session() as session:
        return sorted(set(session.scalars(select(Render.object_id).where(Render.error.is_not(None)))))


def filter_cmd(
    ctx: typer.Context,
    executor: str = typer.Option("local", "--executor", help="local (processes here) or ray (the per-object "
                                 "work as Ray tasks; the catalog is written here: docs/ray.md)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address host:port for --executor "
                                          "ray (default: start a local cluster)."),
    json_out: bool = json_option("the summary"),
) -> None:
    """Flag duplicates and degenerate/outlier objects, exclude all but one per duplicate group (idempotent).
    Exits 3 when an object's descriptors could not be computed (one line each)."""
    from mixcount.curation.finding.catalog_filter import run_filter

    st = state(ctx)
    catalog = st.catalog(write=True)
    try:
        from mixcount.run.catalog_tasks import catalog_executor

        with catalog_executor(executor, address):
            summary = run_filter(catalog, st.config(), progress=RichProgress())
        by_object: dict[str, list[str]] = {}
        for f in summary.descriptor_failures:  # an object may fail more than one descriptor: one line
            by_object.setdefault(f"#{f['id']} {f['name']}", []).append(str(f["error"]))
        failed = [(label, "; ".join(errors)) for label, errors in by_object.items()]
        log = failure_log(catalog, "catalog-filter", failed) if failed else None
    finally:
        catalog.close()
    flags = ", ".join(f"{n} {k}" for k, n in summary.flags.items()) or "none"
    lines = [f"filter: {summary.objects} objects; flags: {flags}; {summary.groups} duplicate groups, "
             f"{summary.excluded} excluded, {summary.review_applied} review decisions applied; to decide: "
             f"{summary.to_decide_objects} objects, {summary.to_decide_pairs} pairs ({summary.candidate_pairs} "
             "candidate pairs compared)"]
    if summary.missing_renders:
        console.print(f"[yellow]{summary.missing_renders} objects have no canonical render: appearance checks "
                      "skipped for them (run `mixcount catalog render`)[/]", highlight=False)
    gt = summary.ground_truth
    if gt is not None:
        kinds = ", ".join(f"{k} {v['found']}/{v['planted']}" for k, v in gt["by_trap"].items())
        lines.append(
            f"ground truth ({gt['ground_truth']}): duplicate pairs precision {gt['precision']:.3f} "
            f"({gt['pairs_correct']}/{gt['pairs_predicted']} predicted pairs correct), "
            f"recall {gt['recall']:.3f} ({gt['pairs_found']}/{gt['pairs_planted']} planted pairs found; {kinds}); broken flagged {gt['broken_flagged']}/{gt['broken_planted']}; "
            f"clean objects with a duplicate flag {gt['clean_with_duplicate_flag']}/{gt['clean_objects']} "
            f"({100 * gt['clean_flag_rate']:.1f} %)")
    result(lines, summary.as_dict(), json_out)
    if failed:
        raise PartialFailure("objects described for the filter", failed, summary.objects, log=str(log),
                             rerun=f"{st.rerun(ctx=ctx)} (idempotent: it tries them again; an object whose model no "
                                   "longer loads fails until its file is fixed or it is excluded)")


def sheet_cmd(
    ctx: typer.Context,
    out_dir: Path = typer.Option(..., "--out", help="Directory for sheet_NNN.png and review.html."),
    only: str = typer.Option("all", "--only", help="Which objects: all | flagged | excluded."),
    category: Optional[str] = typer.Option(None, "--category", help="Only objects of this category."),
    cols: int = typer.Option(6, "--cols", min=1, help="Columns per PNG page."),
    rows: int = typer.Option(5, "--rows", min=1, help="Rows per PNG page."),
    json_out: bool = json_option("what was written"),
) -> None:
    """Write PNG contact sheets and one self-contained HTML review page."""
    from mixcount.curation.review.review_page import write_sheets

    catalog = state(ctx).catalog()
    try:
        written = write_sheets(catalog, out_dir, only=only, category=category, cols=cols, rows=rows)
    finally:
        catalog.close()
    result(f"sheet: {written['objects']} objects, {len(written['pngs'])} PNG page(s) and {written['html']}",
           written, json_out)


@review_app.command("import")
def review_import_cmd(
    ctx: typer.Context,
    file: Path = typer.Argument(..., help="Decisions JSON exported from review.html."),
    reviewer: Optional[str] = typer.Option(None, "--reviewer", help="Reviewer name [default: the file's, else $USER]."),
    other_catalog: bool = typer.Option(
        False, "--other-catalog",
        help="Import a file exported from another catalog (its 'catalog' field names another database: a copy "
             "or a moved catalog); ids and names must still match this one."),
    json_out: bool = json_option("the summary"),
) -> None:
    """Record accept/reject decisions (with reviewer and time) and apply them to object statuses."""
    from mixcount.curation.review.import_decisions import import_decisions

    catalog = state(ctx).catalog(write=True)
    try:
        summary = import_decisions(catalog, file, reviewer=reviewer, other_catalog=other_catalog)
    finally:
        catalog.close()
    for c in summary.status_changes:
        console.print(f"#{c['id']} {escape(c['name'])}: {c['from']} -> {c['to']}", highlight=False, soft_wrap=True)
    for c in summary.container_changes:
        console.print(f"#{c['id']} {escape(c['name'])}: {'now' if c['container'] else 'no longer'} a container",
                      highlight=False, soft_wrap=True)
    result(f"review: {summary.decisions} decisions by {summary.reviewer}: {summary.recorded} recorded, "
           f"{summary.already_recorded} already recorded, {len(summary.status_changes)} status changes",
           summary.as_dict(), json_out)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    catalog_app.command("render")(render_cmd)
    catalog_app.command("filter")(filter_cmd)
    catalog_app.command("sheet")(sheet_cmd)
    catalog_app.add_typer(review_app, name="review")
