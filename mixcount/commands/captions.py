"""CLI: `mixcount catalog caption` and `mixcount catalog split`."""

from __future__ import annotations

import json
import logging
from typing import TYPE_CHECKING, Optional

import typer
from rich.markup import escape

from mixcount.commands.common import RichProgress, console, out, state
from mixcount.config import CaptionsConfig
from mixcount.errors import CatalogError, ConfigError, PartialFailure

if TYPE_CHECKING:
    from mixcount.captions.captioning import CaptionSummary


def make_captioner(kind: str, captions: CaptionsConfig):  # type: ignore[no-untyped-def]
    """Build the captioner named ``kind`` (stub | http) from the ``[captions]`` section."""
    if kind == "stub":
        from mixcount.captions.stub import StubCaptioner

        return StubCaptioner(prompt_version=captions.stub_prompt_version)
    if kind == "http":
        from mixcount.captions.http import HttpCaptioner

        return HttpCaptioner(captions)
    raise ConfigError(f"unknown captioner {kind!r} (stub | http)")


def _summary_text(summary: CaptionSummary, dedupe: bool) -> str:
    """The readable result of ``catalog caption``: counts, collisions per tier and the caption check."""
    tiers = ", ".join(f"{tier} {n}" for tier, n in summary.collisions_by_tier.items()) or "none"
    check = summary.caption_check
    kinds = ", ".join(f"{k} {v}" for k, v in check.get("by_kind", {}).items() if v) or "none"
    return (
        f"captioned {summary.captioned}, skipped {summary.skipped}, failed {summary.failed} of "
        f"{summary.objects} active objects ({summary.captioner}/{summary.provider}/{summary.model}/"
        f"{summary.prompt_version})\n"
        f"caption collisions: {summary.collision_pairs} pairs over {summary.objects_in_collision} objects "
        f"(by tier: {tiers}; {summary.variants_toned} objects told apart before flagging)"
        + (f"; excluded {summary.excluded}" if dedupe else "; kept (--keep-collisions)") + "\n"
        f"caption check: {check.get('objects_warned', 0)} of {check.get('objects_checked', 0)} captioned active "
        f"objects have warnings ({kinds})"
    )


def caption_cmd(
    ctx: typer.Context,
    captioner: Optional[str] = typer.Option(
        None, "--captioner", help="stub (offline, default from captions.captioner) or http (LLM endpoint)."
    ),
    force: bool = typer.Option(False, "--force", help="Caption again even objects this captioner already did."),
    dedupe: bool = typer.Option(
        True, "--dedupe/--keep-collisions",
        help="Default: keep one object per group of identical captions (a person-accepted one, else the lowest "
             "id) and exclude the others, as the paper does. --keep-collisions only flags them "
             "(caption_collision) for review.",
    ),
    json_out: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout instead of a line."),
    executor: str = typer.Option("local", "--executor", help="local (processes here) or ray (the per-object "
                                 "work as Ray tasks; the catalog is written here: docs/ray.md)."),
    address: Optional[str] = typer.Option(None, "--address", help="Ray cluster address host:port for --executor "
                                          "ray (default: start a local cluster)."),
) -> None:
    """Caption every active object at three tiers (short / concise / detailed); resumable. Exits 3 when
    any object failed to caption (one line each; a rerun captions only those)."""
    from mixcount.captions.captioning import caption_catalog

    st = state(ctx)
    cfg = st.config(values={"captions.captioner": captioner})
    conf = cfg.captions
    cap = make_captioner(conf.captioner, conf)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    # each failed object is one `failed:` line at the end (PartialFailure): its log record goes to the
    # handlers a caller configured, not also to Python's last-resort stderr handler
    quiet = logging.getLogger("mixcount.captions")
    if not any(isinstance(h, logging.NullHandler) for h in quiet.handlers):
        quiet.addHandler(logging.NullHandler())
    catalog = st.catalog(write=True)
    try:
        from mixcount.run.catalog_tasks import catalog_executor

        with catalog_executor(executor, address):
            summary = caption_catalog(
                catalog, cap, force=force, dedupe=dedupe, progress=RichProgress(),
                colour_source=conf.colour_source, concurrency=conf.concurrency, palette=cfg.palette,
            )
        from mixcount.catalog.containers import refresh_containers

        with catalog.session() as session:  # captions may name containers ("a wooden tray")
            refresh_containers(session, cfg)
        failed = _failed_items(catalog, summary.failures)
    finally:
        catalog.close()
        close = getattr(cap, "close", None)
        if close is not None:
            close()
    for entry in summary.warnings:
        text = "; ".join(f"{w['tier']}: {w['kind']} ({w['detail']})" for w in entry["warnings"])
        console.print(f"caption check: object {entry['object_id']} {entry['name']}: {text}", highlight=False,
                      markup=False)
    if json_out:
        out.print(json.dumps(summary.as_dict(), sort_keys=True))
    else:
        out.print(_summary_text(summary, dedupe), highlight=False, soft_wrap=True)
    if failed:
        every = summary.failed == summary.objects and not summary.captioned and not summary.skipped
        first = summary.failures[0]["error"] if summary.failures else ""
        headline = (f"every object failed to caption ({summary.failed} of {summary.objects}, captioner "
                    f"{summary.captioner}); first error: {first}") if every else \
            f"captions: {summary.failed} of {summary.captioned + summary.failed} failed (captioner {summary.captioner})"
        rerun = st.rerun(ctx=ctx, drop=("force",))
        raise PartialFailure("captions", failed, summary.captioned + summary.failed, headline=headline,
                             rerun=f"{rerun} (resumable: captions only the objects without captions, the failed ones)")


def _failed_items(catalog, failures: list[dict]) -> list[tuple[str, str]]:  # type: ignore[no-untyped-def]
    """(``#id name``, error) of each object that failed to caption, in id order."""
    from sqlalchemy import select

    from mixcount.catalog.models import CatalogObject

    if not failures:
        return []
    ids = [int(f["object_id"]) for f in failures]
    with catalog.session() as session:
        rows = session.execute(select(CatalogObject.id, CatalogObject.name).where(CatalogObject.id.in_(ids))).all()
    names = {int(row[0]): str(row[1]) for row in rows}
    return [(f"#{f['object_id']} {names.get(int(f['object_id']), '')}".rstrip(), str(f["error"]))
            for f in sorted(failures, key=lambda f: int(f["object_id"]))]


def split_cmd(
    ctx: typer.Context,
    seed: Optional[int] = typer.Option(None, "--seed", help="Seed of the random part [default: split.seed]."),
    mode: Optional[str] = typer.Option(
        None, "--mode", help="paper (FSC-147 classes first, the rest at random), objects (every category kept in "
        "train; val / test hold out objects) or categories (whole categories held out) [default: split.mode]."),
    test_objects: Optional[float] = typer.Option(
        None, "--test-unseen-objects", help="Fraction of objects in an extra split test_objects: unseen objects of "
        "categories train keeps [default: split.test_objects_fraction]."),
    test_categories: Optional[float] = typer.Option(
        None, "--test-unseen-categories", help="Fraction of objects in an extra split test_categories: whole "
        "categories no other split holds [default: split.test_categories_fraction]."),
    check: bool = typer.Option(False, "--check", help="Only check the stored splits for the leaks their mode forbids."),
    report: bool = typer.Option(False, "--report", help="Print what each split holds and what crosses splits "
                                "(with --check: of the stored splits, assigning nothing)."),
    json_out: bool = typer.Option(False, "--json", help="Print the result as JSON on stdout instead of a table."),
) -> None:
    """Assign a split per object (mode paper / objects / categories); exit non-zero on any leak."""
    from rich.table import Table

    from mixcount.catalog.split_classes import FscTable
    from mixcount.catalog.splits import assign_splits, check_splits, split_report

    st = state(ctx)
    conf = st.config(values={"split.seed": seed, "split.mode": mode, "split.test_objects_fraction": test_objects,
                             "split.test_categories_fraction": test_categories}).split
    table = FscTable.load()
    catalog = st.catalog(write=not check)
    try:
        if check:
            leaks = check_splits(catalog, table=table if conf.use_fsc147 else None)
            payload: dict = {"leaks": leaks}
            if report or json_out:
                payload["report"] = split_report(catalog, table=table)
        else:
            summary = assign_splits(catalog, conf, table=table)
            leaks = summary.leaks
            payload = summary.as_dict()
            grid = Table(title=f"object splits (mode {conf.mode}, seed {conf.seed})")
            for col in ("split", "fsc147", "group", "category", "random", "kept", "total", "share", "target"):
                grid.add_column(col, justify="right" if col != "split" else "left", no_wrap=True)
            totals = summary.totals()
            n = max(1, sum(totals.values()))
            for s, total in totals.items():
                c = summary.counts.get(s, {})
                grid.add_row(s, *(str(c.get(m, 0)) for m in ("fsc147", "group", "category", "random", "kept")),
                             str(total), f"{total / n:.0%}", f"{summary.targets.get(s, 0):.0%}")
            (console if json_out else out).print(grid)
            if summary.matched_classes:
                console.print(
                    "FSC-147 matches: "
                    + ", ".join(f"{k} ({table.classes[k]}) x{v}" for k, v in sorted(summary.matched_classes.items())),
                    highlight=False,
                )
            for warning in summary.warnings:
                console.print(f"[yellow]warning:[/] {escape(warning)}", highlight=False, soft_wrap=True)
            if summary.conflicts:
                console.print(f"[yellow]{len(summary.conflicts)} group(s) matched classes of different splits; the most held-out split won[/]")
        if report and not json_out:
            print_split_report(payload["report"])
    finally:
        catalog.close()
    if json_out:
        out.print(json.dumps(payload, sort_keys=True), highlight=False, soft_wrap=True)
    if leaks:
        for leak in leaks:
            console.print(f"[bold red]leak:[/] {escape(leak)}", highlight=False)
        raise CatalogError(f"{len(leaks)} split leak(s) found")
    (console if json_out else out).print("no leaks across splits", highlight=False)


def print_split_report(doc: dict) -> None:
    """The split report (:func:`mixcount.catalog.split_report.report`) as a table and lists on stdout."""
    from rich.table import Table

    grid = Table(title=f"split report (mode {doc['mode']}): {doc['objects']} objects, {doc['categories']} categories",
                 caption="kinds: categories; in train: of them also in train; FSC: FSC-147 classes; variants / "
                         "copies: pairs inside the split")
    for col in ("split", "objects", "kinds", "in train", "FSC", "variants", "copies"):
        grid.add_column(col, justify="left" if col == "split" else "right")
    for s, row in doc["splits"].items():
        grid.add_row(s, str(row["objects"]), str(row["categories"]),
                     "-" if s == "train" else str(row["categories_shared_with_train"]), str(len(row["fsc147_classes"])),
                     str(row["variant_pairs"]), str(row["copy_pairs"]))
    out.print(grid)
    for s, row in doc["splits"].items():
        out.print(f"{s} categories: {', '.join(row['category_names']) or '-'}", highlight=False, soft_wrap=True)
    cross = doc["crossing"]
    out.print(f"categories across splits: {len(cross['categories'])}"
              + "".join(f"\n  {c['category']}: " + ", ".join(f"{s} {k}" for s, k in c["splits"].items())
                        for c in cross["categories"]), highlight=False, soft_wrap=True)
    for kind in ("variant", "copy", "collision", "look_alike"):
        rows = cross[f"{kind}_pairs"]
        if kind == "look_alike":  # many, mostly of other kinds: those of one kind first, ten shown
            rows = sorted(rows, key=lambda r: not r["same_category"])
        out.print(f"{kind.replace('_', '-')} pairs across splits: {len(rows)} of {doc['pairs'][kind]}"
                  + (f" ({sum(r['same_category'] for r in rows)} of one category)" if kind == "look_alike" else "")
                  + "".join(f"\n  {' / '.join(r['names'])}: {' / '.join(r['splits'])}"
                            + ("" if r["same_category"] or kind != "look_alike" else " (other categories)")
                            for r in rows[:10])
                  + (f"\n  ... {len(rows) - 10} more (--json lists all)" if len(rows) > 10 else ""),
                  highlight=False, soft_wrap=True)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    catalog_app.command("caption")(caption_cmd)
    catalog_app.command("split")(split_cmd)
