"""`catalog sheet`: PNG contact sheets and one self-contained HTML review page.

* ``sheet_001.png`` ... : grids of canonical renders (``cols`` x ``rows`` per page) with id, name, the
  three caption tiers under each thumbnail (short, concise, detailed: a person reviews them with the image)
  and the flags (``MESH 0.35`` prints the mesh_quality score;
  ``CONTAINER`` marks containers), framed in a colour per status (green active, orange excluded, red
  broken). Meant to be read at a glance.
* ``review.html``: first the flagged *pairs* (:mod:`mixcount.curation.review.pair_cards`): both renders side
  by side with the evidence and one click for same object / variants, keep both / different; the pairs
  to decide first, then the look-alikes and decided pairs for information. Then every selected object as a card with its thumbnail (inline base64 JPEG), all three
  captions, each flag with its reason and, for pairings, both objects' thumbnails side by side, and
  accept / reject buttons; "export decisions" downloads a ``mixcount-review-v1`` JSON file that
  ``catalog review import`` applies (object decisions and the pairs'). ``--only flagged`` selects the
  objects with a flag to *decide* (:func:`mixcount.curation.flag_kinds.severity`; a usable mesh warning or
  a look-alike is *info*). No external resource is loaded (a CSP forbids it).

Every piece of catalog text (names, captions from an LLM, flag reasons) goes through ``html.escape``;
the JSON embedded for the page's script has ``<``, ``>``, ``&`` and U+2028/9 escaped, so no text can
close the script element or inject markup.
"""

from __future__ import annotations

import base64
import html
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from PIL import Image, ImageDraw, ImageFont
from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.db import Catalog
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.catalog.records import active_captions
from mixcount.curation.flag_kinds import DECIDE, severity
from mixcount.curation.renders import canonical_render_path
from mixcount.curation.review.decisions_file import FORMAT
from mixcount.curation.review.pair_cards import PairView, pair_views, pairs_data, pairs_html
from mixcount.errors import CatalogError
from mixcount.scene.spec import TIERS

ONLY = ("all", "flagged", "excluded")  # flagged: objects with a flag to *decide* (docs/curation.md)
STATUS_COLOURS = {"active": (46, 139, 87), "excluded": (224, 138, 0), "broken": (192, 57, 43)}
TEMPLATE = Path(__file__).with_name("sheet_template.html")
FLAG_SHORT = {
    "exact_duplicate": "EXACT", "near_duplicate_geometry": "GEOM", "near_duplicate_appearance": "LOOK",
    "degenerate": "DEGEN", "size_outlier": "SIZE", "caption_collision": "CAPTION", "mesh_quality": "MESH",
    "colour_variant": "VARIANT", "possible_copy": "COPY?", "look_alike": "ALIKE",
}
# pixels under each thumbnail: name, the three caption tiers (short; concise in 2 lines; detailed in 4), flags
CELL_TEXT_H = 142
SCORED = ("mesh_quality",)  # flags whose score the PNG sheet prints (a warning's severity)


@dataclass
class SheetFlag:
    kind: str
    score: float
    reason: str
    pair: int | None
    pair_name: str | None
    pair_render: Path | None


@dataclass
class SheetEntry:
    id: int
    name: str
    category: str
    status: str
    error: str | None
    render: Path | None
    captions: dict[str, str] | None
    flags: list[SheetFlag] = field(default_factory=list)
    last_review: dict[str, str] | None = None
    container: bool = False
    container_reason: str | None = None
    frame: str = ""  # "mm, Z-up": the unit and up axis ingest read the model in
    frame_reason: str = ""  # why (catalog list --json: units_reason, up_axis_reason)


def collect(session: Session, *, only: str = "all", category: str | None = None) -> list[SheetEntry]:
    """The objects a sheet shows, sorted by category then id."""
    if only not in ONLY:
        raise CatalogError(f"--only must be one of {', '.join(ONLY)}, not {only!r}")
    from mixcount.catalog.decisions import latest_decisions

    query = select(CatalogObject).order_by(CatalogObject.category, CatalogObject.id)
    if category:
        query = query.where(CatalogObject.category == category.lower())
    if only == "excluded":
        query = query.where(CatalogObject.status == "excluded")
    decisions = latest_decisions(session)
    entries = []
    for obj in session.scalars(query):
        flags = session.scalars(select(Flag).where(Flag.object_id == obj.id).order_by(Flag.kind, Flag.id)).all()
        if only == "flagged" and not any(severity(f.kind, f.reason or "") == DECIDE for f in flags):
            continue
        sflags = []
        for f in flags:
            pair = session.get(CatalogObject, f.pair_object_id) if f.pair_object_id is not None else None
            sflags.append(SheetFlag(f.kind, float(f.score), f.reason or "", f.pair_object_id,
                                    pair.name if pair is not None else None,
                                    canonical_render_path(session, pair.id) if pair is not None else None))
        rd = decisions.get(obj.id)
        entries.append(SheetEntry(
            id=obj.id, name=obj.name, category=obj.category, status=obj.status, error=obj.error,
            render=canonical_render_path(session, obj.id), captions=active_captions(session, obj), flags=sflags,
            last_review=({"decision": rd.decision, "reviewer": rd.reviewer, "at": rd.decided_at.isoformat() + "Z",
                          "note": rd.note} if rd is not None else None),
            container=bool(obj.container), container_reason=obj.container_reason,
            frame=f"{obj.source_units}, {obj.source_up_axis}-up" if obj.source_units else "",
            frame_reason=_frame_reason(obj.metadata_json),
        ))
    return entries


def _frame_reason(metadata_json: str | None) -> str:
    """The unit's and the up axis's reasons recorded by ingest, as one line."""
    try:
        info = (json.loads(metadata_json or "{}") or {}).get("ingest") or {}
    except (ValueError, AttributeError):
        return ""
    return "; ".join(f"{k}: {info[r]}" for k, r in (("unit", "units_reason"), ("up", "up_axis_reason")) if info.get(r))


# --------------------------------------------------------------------------- images


def _font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow without FreeType
        return ImageFont.load_default()


def thumbnail(path: Path | None, size: int, label: str = "no render") -> Image.Image:
    """The render scaled to ``size`` on white, or a grey placeholder that says why there is none."""
    if path is not None:
        try:
            with Image.open(path) as im:
                img = im.convert("RGB")
            scale = size / max(img.width, img.height)  # up or down: small quick renders fill the cell too
            img = img.resize((max(1, round(img.width * scale)), max(1, round(img.height * scale))),
                             Image.Resampling.LANCZOS)
            canvas = Image.new("RGB", (size, size), (255, 255, 255))
            canvas.paste(img, ((size - img.width) // 2, (size - img.height) // 2))
            return canvas
        except OSError:
            label = "render unreadable"
    img = Image.new("RGB", (size, size), (225, 225, 225))
    d = ImageDraw.Draw(img)
    font = _font(max(10, size // 12))
    d.text((size // 2, size // 2), label, fill=(90, 90, 90), font=font, anchor="mm")
    return img


def _data_url(img: Image.Image, quality: int = 85) -> str:
    buf = io.BytesIO()
    img.save(buf, format="JPEG", quality=quality, optimize=True)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _fit(draw: ImageDraw.ImageDraw, text: str, font: Any, width: int) -> str:
    """``text`` cut with an ellipsis to fit ``width`` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def _wrap(draw: ImageDraw.ImageDraw, text: str, font: Any, width: int, max_lines: int) -> list[str]:
    """``text`` broken into at most ``max_lines`` lines of ``width`` pixels (the last cut with an ellipsis)."""
    lines: list[str] = []
    line = ""
    words = text.split()
    for i, word in enumerate(words):
        trial = f"{line} {word}".strip()
        if draw.textlength(trial, font=font) <= width or not line:
            line = trial
            continue
        if len(lines) == max_lines - 1:
            return lines + [_fit(draw, " ".join([line] + words[i:]), font, width)]
        lines.append(line)
        line = word
    return lines + ([_fit(draw, line, font, width)] if line else [])


def _flag_line(flags: list[SheetFlag], container: bool = False) -> str:
    parts = ["CONTAINER"] if container else []
    for f in flags:
        tag = FLAG_SHORT.get(f.kind, f.kind.upper())
        if f.kind in SCORED:
            tag = f"{tag} {f.score:.2f}"
        parts.append(f"{tag}~#{f.pair}" if f.pair is not None else tag)
    return " ".join(dict.fromkeys(parts))


def write_png_sheets(entries: list[SheetEntry], out_dir: Path, *, cols: int = 6, rows: int = 5, cell: int = 220,
                     title: str = "mixcount catalog") -> list[Path]:
    """Paged PNG grids; returns the files written (one page at least, empty when nothing is selected)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    per_page = max(1, cols * rows)
    pages = [entries[i:i + per_page] for i in range(0, len(entries), per_page)] or [[]]
    border, text_h, header_h = 6, CELL_TEXT_H, 34
    thumb = cell - 2 * border
    f_title, f_name, f_small = _font(18), _font(13), _font(11)
    paths = []
    for k, page in enumerate(pages, start=1):
        n_rows = max(1, -(-len(page) // cols))
        sheet = Image.new("RGB", (cols * cell, header_h + n_rows * (cell + text_h)), (250, 250, 248))
        d = ImageDraw.Draw(sheet)
        d.text((8, 8), f"{title}: page {k}/{len(pages)}, {len(entries)} objects", fill=(20, 20, 20), font=f_title)
        x0 = cols * cell - 8
        for status in ("broken", "excluded", "active"):
            w = int(d.textlength(status, font=f_small)) + 12
            x0 -= w + 6
            d.rectangle((x0, 9, x0 + w, 25), fill=STATUS_COLOURS[status])
            d.text((x0 + 6, 11), status, fill=(255, 255, 255), font=f_small)
        if not page:
            d.text((8, header_h + 10), "no objects selected", fill=(90, 90, 90), font=f_name)
        for i, e in enumerate(page):
            cx, cy = (i % cols) * cell, header_h + (i // cols) * (cell + text_h)
            colour = STATUS_COLOURS.get(e.status, (120, 120, 120))
            d.rectangle((cx + 1, cy + 1, cx + cell - 2, cy + cell + text_h - 2), fill=colour)
            d.rectangle((cx + border, cy + border, cx + cell - border - 1, cy + cell + text_h - border - 1),
                        fill=(255, 255, 255))
            sheet.paste(thumbnail(e.render, thumb - 4, "broken" if e.status == "broken" else "no render"),
                        (cx + border + 2, cy + border + 2))
            tx, ty, tw = cx + border + 4, cy + cell - border + 2, cell - 2 * border - 8
            d.text((tx, ty), _fit(d, f"#{e.id} {e.name}", f_name, tw), fill=(20, 20, 20), font=f_name)
            caps = e.captions or {}
            short = caps.get("short") or (e.error or "")
            d.text((tx, ty + 17), _fit(d, short, f_name, tw), fill=(20, 20, 90), font=f_name)
            y = ty + 34
            for tier, n_lines, colour in (("concise", 2, (60, 60, 60)), ("detailed", 4, (110, 110, 110))):
                for line in _wrap(d, caps.get(tier) or "", f_small, tw, n_lines):
                    d.text((tx, y), line, fill=colour, font=f_small)
                    y += 13
                y += 2
            d.text((tx, ty + 17 + text_h - 36), _fit(d, _flag_line(e.flags, e.container), f_small, tw),
                   fill=(170, 40, 30), font=f_small)
        path = out_dir / f"sheet_{k:03d}.png"
        sheet.save(path, optimize=True)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------- HTML


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def safe_json(value: Any) -> str:
    """JSON that is inert inside a <script> element (no '</script>', no HTML-significant characters)."""
    text = json.dumps(value, ensure_ascii=False, sort_keys=True)
    return (text.replace("&", "\\u0026").replace("<", "\\u003c").replace(">", "\\u003e")
            .replace("\u2028", "\\u2028").replace("\u2029", "\\u2029"))


def _card(e: SheetEntry, thumbs: dict[int, str], pair_thumbs: dict[int, str]) -> str:
    caps = ""
    if e.captions:
        caps = "<dl class=\"captions\">" + "".join(
            f"<dt>{_e(tier)}</dt><dd class=\"cap-{_e(tier)}\">{_e(e.captions.get(tier, ''))}</dd>"
            for tier in TIERS) + "</dl>"
    else:
        caps = "<p class=\"meta no-captions\">no captions yet</p>"
    flags = []
    for f in e.flags:
        pair_html = ""
        if f.pair is not None:
            pair_html = (
                "<div class=\"pair\">"
                f"<figure><img alt=\"#{e.id}\" src=\"{thumbs[e.id]}\"><figcaption>#{e.id} (this)</figcaption></figure>"
                f"<figure><img alt=\"#{f.pair}\" src=\"{pair_thumbs[f.pair]}\">"
                f"<figcaption><a href=\"#obj-{f.pair}\">#{f.pair}</a> {_e(f.pair_name or '')}</figcaption></figure>"
                "</div>")
        flags.append(f"<li class=\"flag\" data-kind=\"{_e(f.kind)}\" data-pair=\"{_e(f.pair if f.pair is not None else '')}\">"
                     f"<span class=\"kind\">{_e(f.kind)}</span> <span class=\"score\">{f.score:.2f}</span> "
                     f"<span class=\"reason\">{_e(f.reason)}</span>{pair_html}</li>")
    flags_html = f"<ul class=\"flags\">{''.join(flags)}</ul>" if flags else ""
    last = ""
    if e.last_review:
        r = e.last_review
        last = (f"<p class=\"last-review\">last review: {_e(r['decision'])} by {_e(r['reviewer'])} at {_e(r['at'])}"
                + (f" ({_e(r['note'])})" if r.get("note") else "") + "</p>")
    error = f"<p class=\"meta error\">{_e(e.error)}</p>" if e.error else ""
    return (
        f"<article class=\"card status-{_e(e.status)}\" id=\"obj-{e.id}\" data-id=\"{e.id}\" data-status=\"{_e(e.status)}\">"
        f"<h2><span class=\"oid\">#{e.id}</span> <span class=\"name\">{_e(e.name)}</span></h2>"
        f"<div class=\"meta\"><span class=\"category\">{_e(e.category)}</span> · <span class=\"status\">{_e(e.status)}</span>"
        + (f" · <span class=\"frame\" title=\"{_e(e.frame_reason)}\">{_e(e.frame)}</span>" if e.frame else "")
        + "</div>"
        f"<img class=\"thumb\" alt=\"render of {_e(e.name)}\" src=\"{thumbs[e.id]}\">"
        f"{error}{caps}{flags_html}"
        "<div class=\"review\"><button type=\"button\" class=\"accept\" data-decision=\"accept\">accept</button>"
        "<button type=\"button\" class=\"reject\" data-decision=\"reject\">reject</button>"
        f"<label class=\"container\" title=\"{_e(e.container_reason or 'not a container')}\">"
        f"<input class=\"container\" type=\"checkbox\" data-initial=\"{'true' if e.container else 'false'}\""
        f"{' checked' if e.container else ''}> container</label>"
        "<input class=\"note\" type=\"text\" placeholder=\"note\"></div>"
        f"{last}</article>"
    )


def write_html(entries: list[SheetEntry], out_path: Path, *, catalog_url: str = "", thumb: int = 256,
               title: str = "mixcount catalog review", pairs: list[PairView] | None = None) -> Path:
    """One self-contained review page (see the module docstring)."""
    thumbs = {e.id: _data_url(thumbnail(e.render, thumb, "broken" if e.status == "broken" else "no render"))
              for e in entries}

    def side_thumb(oid: int, render: Path | None) -> str:
        if oid not in thumbs:
            thumbs[oid] = _data_url(thumbnail(render, thumb))
        return thumbs[oid]

    pair_section = pairs_html(pairs or [], side_thumb)
    pair_thumbs: dict[int, str] = {}
    for e in entries:
        for f in e.flags:
            if f.pair is not None and f.pair not in pair_thumbs:
                pair_thumbs[f.pair] = _data_url(thumbnail(f.pair_render, 128))
    counts: dict[str, int] = {}
    for e in entries:
        counts[e.status] = counts.get(e.status, 0) + 1
    summary = f"{len(entries)} objects: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    data = {"format": FORMAT, "catalog": catalog_url,
            "objects": {str(e.id): {"name": e.name, "status": e.status} for e in entries},
            "pairs": pairs_data(pairs or [])}
    values = {
        "TITLE": _e(title), "SUMMARY": _e(summary), "PAIRS": pair_section,
        "CARDS": "\n".join(_card(e, thumbs, pair_thumbs) for e in entries), "DATA": safe_json(data),
    }
    page = re.sub(r"@@(TITLE|SUMMARY|PAIRS|CARDS|DATA)@@", lambda m: values[m.group(1)], TEMPLATE.read_text(encoding="utf-8"))
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(page, encoding="utf-8")
    return out_path


def write_sheets(catalog: Catalog, out_dir: Path, *, only: str = "all", category: str | None = None,
                 cols: int = 6, rows: int = 5) -> dict[str, Any]:
    """PNG pages and review.html for the selected objects; returns what was written."""
    with catalog.session() as session:
        entries = collect(session, only=only, category=category)
        views = pair_views(session, {e.id for e in entries})
        if only == "flagged":
            views = [v for v in views if v.severity == DECIDE]
    label = f"mixcount catalog ({only}{', ' + category if category else ''})"
    pngs = write_png_sheets(entries, out_dir, cols=cols, rows=rows, title=label)
    page = write_html(entries, out_dir / "review.html", catalog_url=catalog.engine.url.render_as_string(hide_password=True),
                      title=label + " review", pairs=views)
    return {"objects": len(entries), "pairs": len(views),
            "pairs_to_decide": sum(v.severity == DECIDE for v in views), "pngs": [str(p) for p in pngs], "html": str(page), "only": only,
            "category": category}
