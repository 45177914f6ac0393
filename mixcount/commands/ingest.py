"""CLI: `mixcount catalog ingest`, `catalog list`, `catalog show`."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from mixcount.commands.common import RichProgress, check_catalog_file, console, out, result, state
from mixcount.errors import CatalogError, PartialFailure

SIZE_OF_HELP = ("The real size (largest side: \"14 mm\", \"3.5 in\", \"0.2\" in metres) of every object under FOLDER "
                "whose metadata.json states no \"size\"; repeatable (docs/ingest.md, \"Sizes\").")


def ingest_cmd(
    ctx: typer.Context,
    paths: list[Path] = typer.Argument(..., help="Library folders (any supported layout), object folders or model files."),
    workers: Optional[int] = typer.Option(None, "--workers", "-j", help="Mesh-analysis processes [default: ingest.workers]."),
    strict: bool = typer.Option(False, "--strict", help="Exit non-zero when any object is broken."),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as one JSON object on stdout."),
    layout: str = typer.Option(
        "auto", "--layout",
        help="Library layout: auto (detected per folder), dtc, gso (Google Scanned Objects), objaverse "
             "(model files named by id + side metadata; also Amazon Berkeley Objects), omniobject3d, folder."),
    up_axis: Optional[str] = typer.Option(
        None, "--up-axis",
        help="Up axis (X, Y, Z or auto) of every object whose metadata or layout states none, glTF/GLB "
             "included (Z-up geometry saved as GLB). Kept in the catalog for these folders: a later ingest "
             "without the option keeps it; auto forgets it. Absent: what was stated before, else a URDF/SDF "
             "beside the mesh, STL Z, glTF Y, USD its own, OBJ/PLY ingest.assume_up_axis (docs/ingest.md)."),
    units: Optional[str] = typer.Option(
        None, "--units",
        help="Unit (mm, cm, m, in, ft, or metres per unit; auto: each file's own rule) of every object whose "
             "metadata.json states none, glTF included; USD and STEP state their own. Absent: a URDF/MJCF/SDF "
             "scale beside the mesh, else glTF m, STL mm, OBJ/PLY ingest.assume_units, and an STL/OBJ/PLY "
             "whose size is implausible in that unit is re-read (docs/ingest.md, \"Units\")."),
    parts: str = typer.Option(
        "auto", "--parts",
        help="How a folder's several model files become objects: merge (the parts of one object), separate "
             "(one object per file) or auto (parts when named alike and their boxes touch or nest, or an MJCF "
             "places them in one body). A \"parts\" entry in a folder's metadata.json wins."),
    allow_root: list[Path] = typer.Option(
        [], "--allow-root",
        help="A folder outside the library that its files may reference or link into (repeatable; added to "
             "ingest.extra_roots). Anything else outside the folder named is refused for that object "
             "(docs/ingest.md, \"The library root is the boundary\")."),
    size_of: list[str] = typer.Option([], "--size-of", metavar="FOLDER=SIZE", help=SIZE_OF_HELP),
    metadata: list[Path] = typer.Option(
        [], "--metadata",
        help="Side metadata file (JSON, JSONL or CSV, .gz allowed) mapping model ids to name, category and "
             "licence; repeatable. Files beside the models and in the root's metadata/ folder are found anyway."),
    executor: str = typer.Option("local", "--executor", help="local (processes here) or ray (the per-object "
                                 "work as Ray tasks; the catalog is written here: docs/ray.md)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address host:port for --executor "
                                          "ray (default: start a local cluster)."),
) -> None:
    """Ingest 3D objects: mesh facts in metres/Z-up, hashes, collision meshes; idempotent and resumable."""
    from mixcount.catalog.ingest import check_up_axis, ingest_paths

    st = state(ctx)
    cfg = st.config(values={"ingest.workers": workers})
    # a missing PATH, an unknown layout, a bad --metadata file or a PATH with no model file in it is an
    # error before the database is touched; files in formats ingest does not read are listed, not fatal
    check_catalog_file(st.db)  # a --db that is not a catalog is named first
    repeats: list[tuple[Path, str]] = []
    extra = [*cfg.ingest.extra_roots, *allow_root]
    skipped = _check_inputs(paths, layout, metadata, repeats, extra)
    check_up_axis(up_axis)
    from mixcount.catalog.layouts.parts import check_parts
    from mixcount.catalog.units import check_units

    check_units(units)
    check_parts(parts)
    from mixcount.run.catalog_tasks import catalog_executor

    catalog = st.catalog(create=True)
    try:
        with catalog_executor(executor, address):
            summary = ingest_paths(catalog, paths, config=cfg, progress=RichProgress(), strict=strict,
                                   layout=layout, metadata_files=metadata, up_axis=up_axis, units=units,
                                   parts=parts, size_of=size_of, allow_roots=allow_root)
    except KeyboardInterrupt:
        console.print("[yellow]ingest interrupted:[/] objects finished so far are committed; "
                      "run the same command again to finish", soft_wrap=True)
        raise
    finally:
        catalog.close()
    _print_boundary(summary)
    for line in summary.container_warnings:
        console.print(f"[yellow]warning:[/] {escape(line)}", highlight=False, soft_wrap=True)
    for name, reason in summary.broken_objects:
        console.print(f"[yellow]broken[/] {escape(name)}: {escape(reason)}", highlight=False, soft_wrap=True)
    for name, warning in summary.warnings:
        console.print(f"[yellow]warning:[/] {escape(name)}: {escape(warning)} (kept, flagged)", highlight=False,
                      soft_wrap=True)
    for name, old, new, why in summary.reoriented:
        console.print(f"[yellow]re-oriented[/] {escape(name)}: up axis {old} -> {new} ({escape(why)}); "
                      "give --up-axis to choose", highlight=False, soft_wrap=True)
    for name, unit, why in summary.rescaled:
        if why.startswith("size prior"):
            console.print(f"[yellow]re-read[/] {escape(name)} in {unit}: {escape(why)}; give --units to choose",
                          highlight=False, soft_wrap=True)
        elif why.startswith(("typical size", "stated size")):  # re-sized (issue 70, mixcount.sizes.decide_size)
            console.print(f"[yellow]re-sized[/] {escape(name)}: {escape(why)}", highlight=False, soft_wrap=True)
    for name, why in summary.implausible:
        console.print(f"[yellow]warning:[/] {escape(name)}: {escape(why.split('; ', 1)[-1])}", highlight=False,
                      soft_wrap=True)
    if summary.invalidated:
        console.print(f"{len(summary.invalidated)} changed object(s): their renders, descriptors, flags and captions "
                      "were removed; catalog render / filter / caption redo them", highlight=False, soft_wrap=True)
    found = ", ".join(f"{n} {kind}" for kind, n in sorted(summary.layouts.items()))
    result(
        f"ingested {summary.total} objects: {summary.new} new, {summary.unchanged} unchanged, "
        f"{summary.updated} updated, {summary.broken} broken" + (f" (layouts: {found})" if found else "")
        + (f"; {len(summary.reoriented)} re-oriented" if summary.reoriented else "")
        + (f"; {len(summary.rescaled)} read in a unit other than metres ("
           + ", ".join(f"{n} by {why}" for why, n in summary.as_dict()["rescaled_by"].items()) + ")"
           if summary.rescaled else "")
        + (f"; {len(summary.warnings)} warning(s)" if summary.warnings else "")
        + (f"; skipped {len(skipped)} file(s) in formats not read" if skipped else "")
        + (f"; {len(repeats)} link(s) to what was already walked, read once" if repeats else ""),
        {**summary.as_dict(), "skipped": [{"path": str(p), "reason": r} for p, r in skipped],
         "walked_once": [{"path": str(p), "reason": r} for p, r in repeats]},
        json_out,
    )
    if summary.failed:  # the run failed on these (a crash, an internal error), not their input: exit 3
        raise PartialFailure("catalog ingest", summary.failed, summary.total,
                             rerun="run the same catalog ingest command again: only these are analysed again",
                             headline=f"catalog ingest: {len(summary.failed)} of {summary.total} object(s) failed "
                                      "in this run (not in their files)")
    if strict and summary.broken:
        raise CatalogError(f"{summary.broken} broken object(s) (--strict)")


SKIPPED_LINES = 20  # skipped files named one per line; the rest are counted


def _print_boundary(summary) -> None:  # type: ignore[no-untyped-def]
    """What the run closed, refused and ignored: earlier runs left running, links and files outside the
    library (once each, 20 lines then a count), metadata entries of another meaning (once per value)."""
    for run_id in summary.interrupted_runs:
        console.print(f"[yellow]closed:[/] ingest run {run_id} was left running by a process that is gone: "
                      "recorded as interrupted", highlight=False, soft_wrap=True)
    if summary.refused:
        console.print(f"[yellow]refused {len(summary.refused)} link(s) or file(s)[/] leading outside the library "
                      "(not followed, not read; --allow-root DIR to allow a folder):", highlight=False,
                      soft_wrap=True)
        for p, reason in summary.refused[:SKIPPED_LINES]:
            console.print(f"  {escape(p)}: {escape(reason)}", highlight=False, soft_wrap=True)
        if len(summary.refused) > SKIPPED_LINES:
            console.print(f"  ... and {len(summary.refused) - SKIPPED_LINES} more (all listed by --json)",
                          highlight=False)
    for (entry, expected), n in sorted(summary.ignored.items()):
        console.print(f"[yellow]ignored[/] {escape(entry)} in {n} object(s): not {escape(expected)}",
                      highlight=False, soft_wrap=True)


def _check_inputs(paths: list[Path], layout: str, metadata: list[Path],
                  repeats: list[tuple[Path, str]], extra_roots: list[str | Path]) -> list[tuple[Path, str]]:
    """Walk every PATH once before the database is opened: a PATH with no model file in it is an error
    that names it (with what was skipped there), and the files in formats ingest does not read are
    reported on stderr by name, with a count per format, as are the links not followed again (loops,
    repeated targets: appended to ``repeats``). Returns the skipped (path, reason) pairs."""
    from mixcount.catalog.ingest import discover
    from mixcount.catalog.layouts.discovery import UNREAD_MODEL_FORMATS
    from mixcount.catalog.mesh import MESH_EXTENSIONS
    from mixcount.catalog.naming import safe_text

    skipped: list[tuple[Path, str]] = []
    for path in paths:
        here: list[tuple[Path, str]] = []
        if not discover([path], layout=layout, metadata_files=metadata, skipped=here, repeats=repeats,
                        allowed=extra_roots):
            what = (f": only {len(here)} file(s) in formats ingest does not read ("
                    + ", ".join(sorted({p.suffix.lower() for p, _ in here})) + ")") if here else ""
            raise CatalogError(
                f"no model file to ingest under {path}{what}; ingest reads "
                + ", ".join(sorted(MESH_EXTENSIONS)) + " (convert others to GLB, e.g. in Blender); nothing was ingested")
        skipped.extend(here)
    if skipped:
        by_format = Counter(p.suffix.lower() for p, _ in skipped)
        console.print(
            f"[yellow]skipped {len(skipped)} file(s)[/] in formats ingest does not read ("
            + ", ".join(f"{n} {ext} {UNREAD_MODEL_FORMATS[ext]}" for ext, n in sorted(by_format.items()))
            + "): convert them to GLB to ingest them; the other objects are ingested", highlight=False,
            soft_wrap=True)
        for p, reason in skipped[:SKIPPED_LINES]:
            console.print(f"  skipped {escape(str(p))}: {escape(reason)}", highlight=False, soft_wrap=True)
        if len(skipped) > SKIPPED_LINES:
            console.print(f"  ... and {len(skipped) - SKIPPED_LINES} more (all listed by --json)", highlight=False)
    if repeats:
        console.print(f"[yellow]read once:[/] {len(repeats)} link(s) lead to a folder or file already walked "
                      "(each real folder is read once)", highlight=False, soft_wrap=True)
        for p, reason in repeats[:SKIPPED_LINES]:
            console.print(f"  {escape(safe_text(str(p)))}: {escape(safe_text(reason))}", highlight=False, soft_wrap=True)
        if len(repeats) > SKIPPED_LINES:
            console.print(f"  ... and {len(repeats) - SKIPPED_LINES} more (all listed by --json)", highlight=False)
    return skipped


def _query(session, status: Optional[str], category: Optional[str]):  # type: ignore[no-untyped-def]
    from sqlalchemy import select

    from mixcount.catalog.models import STATUSES, CatalogObject

    stmt = select(CatalogObject).order_by(CatalogObject.id)
    if status:
        if status not in STATUSES:
            raise CatalogError(f"unknown status {status!r} (expected one of {', '.join(STATUSES)})")
        stmt = stmt.where(CatalogObject.status == status)
    if category:
        stmt = stmt.where(CatalogObject.category == category.lower())
    return session.scalars(stmt).all()


def summary_of(objects) -> dict:  # type: ignore[no-untyped-def]
    """Counts by status and by category (category counts cover every status)."""
    by_status = Counter(o.status for o in objects)
    by_category: dict[str, dict[str, int]] = {}
    for o in objects:
        row = by_category.setdefault(o.category, {"total": 0, "active": 0, "excluded": 0, "broken": 0})
        row["total"] += 1
        row[o.status] = row.get(o.status, 0) + 1
    return {
        "total": len(objects),
        "by_status": {s: by_status.get(s, 0) for s in ("active", "excluded", "broken")},
        "by_category": dict(sorted(by_category.items())),
    }


def list_cmd(
    ctx: typer.Context,
    status: Optional[str] = typer.Option(None, "--status", help="Only objects with this status (active|excluded|broken)."),
    category: Optional[str] = typer.Option(None, "--category", help="Only objects of this category."),
    json_out: bool = typer.Option(False, "--json", help="Print a JSON array (see docs/catalog-json.md)."),
    summary: bool = typer.Option(False, "--summary", help="Counts by status and category instead of rows."),
) -> None:
    """List catalog objects."""
    from rich.table import Table

    from mixcount.captions.check import object_warnings
    from mixcount.catalog.records import object_record
    from mixcount.catalog.units import shown_unit, units_reason_of

    catalog = state(ctx).catalog()
    try:
        with catalog.session() as session:
            objects = _query(session, status, category)
            if summary:
                data = summary_of(objects)
                if json_out:
                    out.print(json.dumps(data, sort_keys=True))
                    return
                s = data["by_status"]
                out.print(
                    f"{data['total']} objects: {s['active']} active, {s['excluded']} excluded, {s['broken']} broken; "
                    f"{len(data['by_category'])} categories"
                )
                table = Table(title="catalog by category")
                for col in ("category", "total", "active", "excluded", "broken"):
                    table.add_column(col, justify="left" if col == "category" else "right")
                for cat, row in data["by_category"].items():
                    table.add_row(cat, *(str(row[k]) for k in ("total", "active", "excluded", "broken")))
                out.print(table)
                return
            if json_out:
                out.print(json.dumps([object_record(session, o, caption_warnings=object_warnings(session, o))
                                      for o in objects], sort_keys=True))
                return
            table = Table(title=f"{len(objects)} objects")
            for col in ("id", "name", "category", "status", "dims (cm)", "unit / up", "faces", "error"):
                table.add_column(col)
            for o in objects:
                dims = "x".join(f"{d * 100:.1f}" for d in o.dims) if o.dim_x is not None else ""
                unit = shown_unit(o.source_units, units_reason_of(o.metadata_json))  # a STEP's own mm, not "m"
                frame = f"{unit} / {o.source_up_axis or ''}" if o.source_units else ""
                frame += f" (size: {o.size_source})" if frame and o.size_source not in (None, "model") else ""
                table.add_row(str(o.id), o.name, o.category, o.status, dims, frame, str(o.face_count or ""),
                              (o.error or "")[:60])
            out.print(table)
    finally:
        catalog.close()


def show_cmd(
    ctx: typer.Context,
    object_id: str = typer.Argument(..., metavar="ID", help="Object id (or exact name)."),
    json_out: bool = typer.Option(False, "--json", help="Print the object as JSON (see docs/catalog-json.md)."),
) -> None:
    """Show every fact, flag, caption and the split of one object."""
    from sqlalchemy import select

    from mixcount.captions.check import object_warnings
    from mixcount.catalog.models import CatalogObject
    from mixcount.catalog.records import object_record
    from mixcount.catalog.units import shown_unit

    catalog = state(ctx).catalog()
    try:
        with catalog.session() as session:
            obj = session.get(CatalogObject, int(object_id)) if object_id.isdigit() else None
            if obj is None:
                obj = session.scalars(select(CatalogObject).where(CatalogObject.name == object_id)).first()
            if obj is None:
                raise CatalogError(f"no catalog object with id or name {object_id!r}")
            record = object_record(session, obj, caption_warnings=object_warnings(session, obj), detail=True)
    finally:
        catalog.close()
    if json_out:
        out.print(json.dumps(record, sort_keys=True))
        return
    width = max(len(k) for k in record)
    for key, value in record.items():
        text = json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else "-" if value is None else str(value)
        if key == "source_units" and value:  # the file's own unit (a STEP's mm), and the one it was read into
            own = shown_unit(str(value), record.get("units_reason"))
            text = text if own == value else f"{own} (read into {value})"
        out.print(f"{key:<{width}}  {text}")


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    catalog_app.command("ingest")(ingest_cmd)
    catalog_app.command("list")(list_cmd)
    catalog_app.command("show")(show_cmd)
