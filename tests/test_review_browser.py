"""The HTML review page in real headless Chromium (Debian's `chromium`, driven by Playwright without any
browser download): the right number of cards, a caption holding `<script>` shown as text and never run,
reject + export giving the expected decisions file, and importing that file changing the catalog."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from test_curate_support import add_captions, library_catalog, quick_config

from mixcount.catalog.models import CatalogObject, ReviewDecision
from mixcount.cli import main
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.curation.review.decisions_file import FORMAT
from mixcount.curation.review.review_page import write_sheets

pytestmark = [pytest.mark.browser]

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-background-networking",
        "--disable-component-update", "--no-first-run", "--disable-extensions"]
CAPTION = '<script>window.pwned = 1</script> a yellow cone & "friends"'


@pytest.fixture
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        if IN_CI:
            raise
        pytest.skip("playwright is not installed (pip install -e '.[dev]')")
    if not Path(CHROMIUM).exists():
        if IN_CI:
            pytest.fail("chromium is missing (make browser)")
        pytest.skip("chromium is not installed (make browser)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        try:
            yield b
        finally:
            b.close()


def test_review_page_round_trip(browser, catalog, tmp_path):
    objs = library_catalog(catalog, tmp_path)
    run_filter(catalog, quick_config())
    cone, cyl = objs["cone"], objs["cyl"]
    add_captions(catalog, cone.id, CAPTION)
    page_path = Path(write_sheets(catalog, tmp_path / "sheet")["html"])

    context = browser.new_context(accept_downloads=True)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(page_path.as_uri())

    assert page.locator("article.card").count() == 11
    assert page.locator(f"#obj-{cone.id} .cap-short").text_content() == CAPTION
    assert page.evaluate("typeof window.pwned") == "undefined"
    assert page.locator("#cards script").count() == 0
    # every card's thumbnail decoded (inline data, nothing fetched)
    assert page.evaluate("[...document.querySelectorAll('img.thumb')].every(i => i.complete && i.naturalWidth > 0)")

    page.fill("#reviewer", "tester")
    page.click(f"#obj-{cone.id} button.reject")
    page.fill(f"#obj-{cone.id} input.note", "odd <b>cone</b>")
    page.click(f"#obj-{cyl.id} button.accept")
    page.click(f"#obj-{cyl.id} button.accept")  # a second click withdraws the decision
    assert page.text_content("#pending") == "1 decision"
    page.check(f"#obj-{cyl.id} input.container")  # mark a container: a decision of its own
    assert page.text_content("#pending") == "2 decisions"
    assert "pending-reject" in (page.get_attribute(f"#obj-{cone.id}", "class") or "")
    with page.expect_download() as info:
        page.click("#export")
    download = info.value
    out = tmp_path / "decisions.json"
    download.save_as(out)
    assert download.suggested_filename == "mixcount-decisions.json"
    assert not errors
    context.close()

    data = json.loads(out.read_text())
    assert data["format"] == FORMAT and data["reviewer"] == "tester"
    assert len(data["decisions"]) == 2
    decision = next(d for d in data["decisions"] if d["id"] == cone.id)
    assert {k: decision[k] for k in ("id", "name", "decision", "note")} == {
        "id": cone.id, "name": cone.name, "decision": "reject", "note": "odd <b>cone</b>"}
    assert decision["decided_at"].endswith("Z") and "container" not in decision
    marked = next(d for d in data["decisions"] if d["id"] == cyl.id)
    assert marked["container"] is True and "decision" not in marked

    with catalog.session() as s:
        cyl_status = s.get(CatalogObject, cyl.id).status  # as the filter left it
    assert main(["--db", str(tmp_path / "catalog.db"), "catalog", "review", "import", str(out)]) == 0
    with catalog.session() as s:
        assert s.get(CatalogObject, cone.id).status == "excluded"
        row = s.query(ReviewDecision).filter_by(object_id=cone.id).one()
        assert (row.decision, row.reviewer, row.note) == ("reject", "tester", "odd <b>cone</b>")
        container = s.get(CatalogObject, cyl.id)
        assert container.container and container.container_reason.startswith("review: container by tester")
        assert container.status == cyl_status  # a container setting is not an accept/reject


def test_pair_review_round_trip_survives_filter(browser, catalog, tmp_path):
    """The pair-centred page: the exact copies (box / box_copy, one excluded by the filter) shown as one pair
    card with both renders and the evidence; a click on "different" and one on "variants, keep both" for
    the recoloured cylinder, export, `catalog review import`: the excluded copy is active again, the
    decisions are recorded with their pair, the pairs' flags become information (``--only flagged`` drops
    them), and a re-run of `catalog filter` keeps all of it."""
    objs = library_catalog(catalog, tmp_path)
    config = quick_config()
    run_filter(catalog, config)
    box, copy, cyl, recolour = objs["box"], objs["box_copy"], objs["cyl"], objs["cyl_recolour"]
    with catalog.session() as s:
        assert sorted(s.get(CatalogObject, i).status for i in (box.id, copy.id)) == ["active", "excluded"]
    written = write_sheets(catalog, tmp_path / "sheet", only="flagged")
    box_key, cyl_key = f"{min(box.id, copy.id)}-{max(box.id, copy.id)}", f"{min(cyl.id, recolour.id)}-{max(cyl.id, recolour.id)}"

    context = browser.new_context(accept_downloads=True)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(Path(written["html"]).as_uri())
    card = f"#pair-{box_key}"
    assert page.locator(f"#pairs-decide {card}").count() == 1
    assert page.locator(f"{card} img.pthumb").count() == 2
    assert page.evaluate(f"[...document.querySelectorAll('{card} img.pthumb')].every(i => i.complete && i.naturalWidth > 0)")
    assert "exact_duplicate" in (page.text_content(f"{card} ul.evidence") or "")
    assert " cm" in (page.text_content(f"{card} .sides") or "")  # the sizes, beside the sources
    page.fill("#reviewer", "pat")
    page.click(f"{card} button.pair-decision.different")
    page.fill(f"{card} input.pair-note", "two boxes")
    page.click(f"#pair-{cyl_key} button.pair-decision.same")
    page.click(f"#pair-{cyl_key} button.pair-decision.variants")  # a second choice replaces the first
    assert page.text_content("#pending") == "2 decisions"
    with page.expect_download() as info:
        page.click("#export")
    out = tmp_path / "decisions.json"
    info.value.save_as(out)
    assert not errors
    context.close()

    data = json.loads(out.read_text())
    assert data["decisions"] == []
    assert [(p["a"], p["b"], p["decision"]) for p in data["pairs"]] == sorted([
        (min(box.id, copy.id), max(box.id, copy.id), "different"),
        (min(cyl.id, recolour.id), max(cyl.id, recolour.id), "variants")])
    assert next(p for p in data["pairs"] if p["decision"] == "different")["note"] == "two boxes"

    db = ["--db", str(tmp_path / "catalog.db")]
    assert main(db + ["catalog", "review", "import", str(out)]) == 0

    def check() -> None:
        with catalog.session() as s:
            assert [s.get(CatalogObject, i).status for i in (box.id, copy.id, cyl.id, recolour.id)] == ["active"] * 4
            rows = s.query(ReviewDecision).filter(ReviewDecision.pair_object_id.is_not(None)).all()
            assert sorted((r.decision, r.reviewer) for r in rows) == [("different", "pat"), ("variants", "pat")]
        flagged = write_sheets(catalog, tmp_path / "again", only="flagged")
        html = Path(flagged["html"]).read_text()
        assert f"pair-{box_key}" not in html and f"pair-{cyl_key}" not in html  # decided: information now
        everything = Path(write_sheets(catalog, tmp_path / "all")["html"]).read_text()
        info = everything[everything.index('id="pairs-info"'):]
        assert f"pair-{box_key}" in info and "decided: different" in info

    check()
    run_filter(catalog, config)  # a re-run of the filter keeps the person's decisions
    check()
