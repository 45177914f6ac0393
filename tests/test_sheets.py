"""Contact sheets and the review round-trip without a browser: paged PNG grids with status borders,
selection by --only/--category, every text escaped in the HTML page and its embedded JSON, and
`catalog review import` (validation, reviewer and time stored, idempotent, surviving `filter`)."""

from __future__ import annotations

import html
import json
import re
from datetime import datetime

import numpy as np
import pytest
from PIL import Image
from sqlalchemy import select
from test_curate_support import add_captions, library_catalog, quick_config

from mixcount.catalog.models import CatalogObject, ReviewDecision
from mixcount.cli import main
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.curation.flag_kinds import severity
from mixcount.curation.review.decisions_file import FORMAT
from mixcount.curation.review.import_decisions import import_decisions
from mixcount.curation.review.review_page import CELL_TEXT_H, STATUS_COLOURS, collect, safe_json, write_sheets
from mixcount.errors import CatalogError

HOSTILE = "</script><script>window.pwned=1</script><img src=x onerror=\"window.pwned=2\"> & \u2028 'q'"


@pytest.fixture
def curated(catalog, tmp_path):
    objs = library_catalog(catalog, tmp_path)
    run_filter(catalog, quick_config())
    add_captions(catalog, objs["cone"].id, HOSTILE)
    return objs


def test_png_pages_borders_and_selection(catalog, curated, tmp_path):
    result = write_sheets(catalog, tmp_path / "all", cols=3, rows=2)
    assert result["objects"] == 11 and len(result["pngs"]) == 2  # 6 per page
    with catalog.session() as s:
        entries = collect(s)
    with Image.open(result["pngs"][0]) as im:
        px = np.asarray(im.convert("RGB"))
    header = 34
    for i, entry in enumerate(entries[:6]):  # the frame of each cell has its status colour
        x, y = (i % 3) * 220 + 3, header + (i // 3) * (220 + CELL_TEXT_H) + 3
        assert tuple(px[y, x]) == STATUS_COLOURS[entry.status], (i, entry.name, entry.status)
    assert {e.status for e in entries} == {"active", "excluded"}

    flagged = write_sheets(catalog, tmp_path / "flagged", only="flagged")
    with catalog.session() as s:
        n_flagged = sum(1 for e in collect(s) if e.flags)
        n_decide = sum(1 for e in collect(s) if any(severity(f.kind, f.reason) == "decide" for f in e.flags))
        n_excluded = s.query(CatalogObject).filter_by(status="excluded").count()
    # --only flagged: what needs a decision (a look-alike, a usable mesh warning is information only)
    # (the two plain grey balls, one rescaled, are a look-alike for information since issue 57: a plain surface
    # is no evidence of a copy; box and box copy, the cylinders, the flat sheet and the giant are to decide)
    assert flagged["objects"] == n_decide == 6 and n_flagged == 9
    # box copy and the flat sheet (the recoloured cylinder is a colour variant: active; the balls stay)
    assert write_sheets(catalog, tmp_path / "ex", only="excluded")["objects"] == n_excluded == 2
    one_cat = write_sheets(catalog, tmp_path / "cat", category=curated["cone"].category)
    assert one_cat["objects"] == 1
    empty = write_sheets(catalog, tmp_path / "none", category="no-such-category")
    assert empty["objects"] == 0 and len(empty["pngs"]) == 1
    with pytest.raises(CatalogError):
        write_sheets(catalog, tmp_path / "bad", only="everything")


def test_html_escapes_everything(catalog, curated, tmp_path):
    page = (tmp_path / "s" / "review.html")
    write_sheets(catalog, tmp_path / "s")
    text = page.read_text(encoding="utf-8")
    assert "window.pwned" in text  # the caption is there ...
    assert "<script>window.pwned" not in text and "<img src=x" not in text  # ... but never as markup
    assert html.escape(HOSTILE, quote=True) in text
    assert text.count("<script") == 2  # the page's own data block and code, nothing else
    assert 'src="http' not in text and "href=\"http" not in text  # self-contained
    data = re.search(r'<script type="application/json" id="mixcount-data">(.*?)</script>', text, re.S).group(1)
    assert "<" not in data and ">" not in data
    parsed = json.loads(data)
    assert parsed["format"] == FORMAT and len(parsed["objects"]) == 11
    assert json.loads(safe_json({"t": HOSTILE})) == {"t": HOSTILE}
    # pairs are shown side by side: the flagged copy's card holds both thumbnails
    card = re.search(rf'<article[^>]*id="obj-{curated["box_copy"].id}".*?</article>', text, re.S).group(0)
    n_pairs = card.count('class="pair"')  # the exact copy, and a look-alike (information)
    assert 'data-kind="exact_duplicate"' in card and n_pairs >= 1
    assert card.count("data:image/jpeg;base64,") == 1 + 2 * n_pairs


def write_decisions(path, decisions, reviewer="ana"):
    path.write_text(json.dumps({"format": FORMAT, "reviewer": reviewer, "exported_at": "2026-11-23T10:00:00.000Z",
                                "decisions": decisions}))
    return path


def test_review_import_validates_records_and_survives_filter(catalog, curated, tmp_path, capsys):
    # cyl: the box copy the filter excluded (lower id kept), which the person accepts
    cone, cyl = curated["cone"], max(curated["box"], curated["box_copy"], key=lambda o: o.id)
    bad = [
        [{"id": 9999, "decision": "reject"}],
        [{"id": cone.id, "name": "not the cone", "decision": "reject"}],
        [{"id": cone.id, "decision": "maybe"}],
        [{"id": cone.id, "decision": "reject"}, {"id": "x", "decision": "accept"}],
    ]
    for k, decisions in enumerate(bad):
        with pytest.raises(CatalogError, match="nothing applied"):
            import_decisions(catalog, write_decisions(tmp_path / f"bad{k}.json", decisions))
    with pytest.raises(CatalogError):
        import_decisions(catalog, tmp_path / "missing.json")
    (tmp_path / "other.json").write_text('{"decisions": []}')
    with pytest.raises(CatalogError, match="not a"):
        import_decisions(catalog, tmp_path / "other.json")
    with catalog.session() as s:
        assert s.query(ReviewDecision).count() == 0
        assert s.get(CatalogObject, cone.id).status == "active"

    good = write_decisions(tmp_path / "good.json", [
        {"id": cone.id, "name": cone.name, "decision": "reject", "note": "looks odd",
         "decided_at": "2026-11-23T09:59:30.250Z"},
        {"id": cyl.id, "name": cyl.name, "decision": "accept", "note": ""},
    ])
    db = str(tmp_path / "catalog.db")
    assert main(["--db", db, "catalog", "review", "import", str(good), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["recorded"] == 2 and summary["reviewer"] == "ana"
    assert {(c["id"], c["to"]) for c in summary["status_changes"]} == {(cone.id, "excluded"), (cyl.id, "active")}
    with catalog.session() as s:
        rows = {r.object_id: r for r in s.scalars(select(ReviewDecision))}
        assert rows[cone.id].reviewer == "ana" and rows[cone.id].note == "looks odd"
        assert rows[cone.id].decided_at == datetime(2026, 11, 23, 9, 59, 30, 250000)
        assert rows[cyl.id].decided_at == datetime(2026, 11, 23, 10, 0, 0)  # the file's export time

    again = import_decisions(catalog, good, reviewer="ana")
    assert (again.recorded, again.already_recorded, again.status_changes) == (0, 2, [])

    run_filter(catalog, quick_config())  # the person's word survives re-running the filter
    with catalog.session() as s:
        assert s.get(CatalogObject, cone.id).status == "excluded"
        assert s.get(CatalogObject, cyl.id).status == "active"
