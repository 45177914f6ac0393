"""CLI: `mixcount catalog caption` and `mixcount catalog split`."""

from __future__ import annotations

import json
import logging
from typing import TYPE_CHECKING, Optional

import typer
from rich.markup import escape

from mixcount.commands.common import RichProgress, console, out, state
from mixcount.config import CaptionsConfig
from mixcount.errors import CaptionError, CatalogError, ConfigError

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
) -> None:
    """Caption every active object at three tiers (short / concise / detailed); resumable."""
    from mixcount.captions.captioning import caption_catalog

    st = state(ctx)
    cfg = st.config(values={"captions.captioner": captioner})
    conf = cfg.captions
    cap = make_captioner(conf.captioner, conf)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    catalog = st.catalog()
    try:
        summary = caption_catalog(
            catalog, cap, force=force, dedupe=dedupe, progress=RichProgress(),
            colour_source=conf.colour_source, concurrency=conf.concurrency,
        )
        from mixcount.catalog.containers import refresh_containers

        with catalog.session() as session:  # captions may name containers ("a wooden tray")
            refresh_containers(session, cfg)
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
    if summary.failed and summary.failed == summary.objects and not summary.captioned and not summary.skipped:
        first = summary.failures[0]["error"] if summary.failures else ""
        raise CaptionError(
            f"every object failed to caption ({summary.failed} of {summary.objects}, captioner "
            f"{summary.captioner}); first error: {first}"
        )


def split_cmd(
    ctx: typer.Context,
    seed: Optional[int] = typer.Option(None, "--seed", help="Seed of the random part [default: split.seed]."),
    check: bool = typer.Option(False, "--check", help="Only check the stored splits for leaks."),
    json_out: bool = typer.Option(False, "--json", help="Print the result as JSON on stdout instead of a table."),
) -> None:
    """Assign train / val / test per object (FSC-147 matches first); exit non-zero on any leak."""
    from rich.table import Table

    from mixcount.catalog.splits import SPLITS, FscTable, assign_splits, check_splits

    st = state(ctx)
    conf = st.config(values={"split.seed": seed}).split
    table = FscTable.load()
    catalog = st.catalog()
    try:
        if check:
            leaks = check_splits(catalog, table=table if conf.use_fsc147 else None)
            payload: dict = {"leaks": leaks}
        else:
            summary = assign_splits(catalog, conf, table=table)
            leaks = summary.leaks
            payload = summary.as_dict()
            grid = Table(title=f"object splits (seed {conf.seed})")
            for col in ("split", "fsc147", "group", "random", "total", "share", "target"):
                grid.add_column(col, justify="right" if col != "split" else "left")
            totals = summary.totals()
            n = max(1, sum(totals.values()))
            for s in SPLITS:
                c = summary.counts.get(s, {})
                grid.add_row(
                    s, str(c.get("fsc147", 0)), str(c.get("group", 0)), str(c.get("random", 0)), str(totals[s]),
                    f"{totals[s] / n:.0%}", f"{summary.targets[s]:.0%}",
                )
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
                console.print(f"[yellow]{len(summary.conflicts)} duplicate group(s) matched classes of different splits; the most held-out split won[/]")
    finally:
        catalog.close()
    if json_out:
        out.print(json.dumps(payload, sort_keys=True))
    if leaks:
        for leak in leaks:
            console.print(f"[bold red]leak:[/] {escape(leak)}", highlight=False)
        raise CatalogError(f"{len(leaks)} split leak(s) found")
    (console if json_out else out).print("no leaks across splits", highlight=False)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    catalog_app.command("caption")(caption_cmd)
    catalog_app.command("split")(split_cmd)
