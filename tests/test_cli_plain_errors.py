"""Every user error is one plain line (issue 60): exit 2, no traceback, printed as given (no rich markup,
no emoji codes, control characters escaped); numbers out of range, deep or huge JSON, a damaged catalog
(named, with how to recover it) and Ctrl-C (exit 130, what was kept and how to go on)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
import typer
from sqlalchemy import select
from test_compose_orchestration import FakeWorker, _pool

from mixcount import cli
from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject
from mixcount.config import load_config
from mixcount.errors import StoppedByUser
from mixcount.run.compose import compose_scenes
from mixcount.run.local import LocalExecutor
from mixcount.run.scene_task import run_scene_task

HOSTILE = "[red]secret[/red]:x:"


def _lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.strip()]


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    code = cli.main(argv)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out
    return code, _lines(captured.err)


@pytest.fixture(scope="module")
def small_catalog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A migrated catalog with a few objects (no model files: `catalog list` reads rows only)."""
    path = tmp_path_factory.mktemp("plain") / "catalog.db"
    cat = open_catalog(str(path), data_dir="")
    with cat.session() as s:
        for i in range(40):
            s.add(CatalogObject(source="folder", source_id=f"o{i}", name=f"object {i} " + "x" * 200,
                                category="mug", model_path=f"/nowhere/{i}.obj", status="active"))
        s.commit()
        assert len(s.scalars(select(CatalogObject)).all()) == 40
    cat.engine.dispose()
    con = sqlite3.connect(path)
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    return path


def test_markup_and_emoji_codes_in_a_path_are_printed_as_given(small_catalog: Path, tmp_path: Path, capsys) -> None:
    bad = tmp_path / "reviews" / f"{HOSTILE}.json"  # the path: a folder "[red]secret[" in reviews/
    bad.parent.mkdir(parents=True)
    bad.write_text('{"images": [', encoding="utf-8")
    code, lines = run_cli(["--db", str(small_catalog), "compose", "--counts", f"histogram:{bad}", "--dry-run"],
                          capsys)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"error: count target histogram {bad}: not valid JSON"), lines
    code, lines = run_cli(["--config", str(tmp_path / f"{HOSTILE}.toml"), "catalog", "list"], capsys)
    assert code == 2 and lines == [f"error: config file not found: {tmp_path / f'{HOSTILE}.toml'}"]


def test_a_newline_in_a_path_stays_on_one_line(tmp_path: Path, capsys) -> None:
    name = tmp_path / "two\nlines.toml"
    code, lines = run_cli(["--config", str(name), "catalog", "list"], capsys)
    assert code == 2 and lines == [f"error: config file not found: {tmp_path}/two\\nlines.toml"]


@pytest.mark.parametrize("target, says", [
    ("uniform:1-99999999999999999999", "goes past 10,000"),
    ("uniform:1-" + "9" * 400, "goes past 10,000"),
    ("uniform:1.2.3-5", "must be LOW-HIGH"),
    ("uniform:1-5,imbalance:1-1e9", "must be LOW-HIGH"),
    ("uniform:1-5,imbalance:1-20000", "goes past 10,000"),
])
def test_numbers_out_of_range_are_one_line(target: str, says: str, small_catalog: Path, capsys) -> None:
    code, lines = run_cli(["--db", str(small_catalog), "compose", "--counts", target, "--dry-run"], capsys)
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: count target") and says in lines[0], lines
    assert len(lines[0]) < 300, "the error quotes a cut of the text, not all of it"


@pytest.mark.parametrize("doc, says", [
    ("[" * 100_000 + "]" * 100_000, "nested deeper than a JSON reader follows"),
    ('{"a": {"points": [[1, 2]]}, "b": {"points": [' + ",".join(["[0, 0]"] * 10_001) + "]}}",
     "image 'b' holds 10,001 objects, more than the 10,000"),
    ('{"images": [{"id": 1}], "annotations": [{"image_id": 1, "category_id": 1, "area": ' + "9" * 5000 + "}]}",
     "a number too long to read"),
])
def test_deep_or_huge_count_files_are_one_line(doc: str, says: str, small_catalog: Path, tmp_path: Path,
                                              capsys) -> None:
    path = tmp_path / "counts.json"
    path.write_text(doc, encoding="utf-8")
    code, lines = run_cli(["--db", str(small_catalog), "compose", "--counts", f"histogram:{path}",
                           "--dry-run"], capsys)
    assert code == 2 and len(lines) == 1 and says in lines[0], lines


def test_a_damaged_catalog_is_named_with_how_to_recover_it(small_catalog: Path, tmp_path: Path, capsys) -> None:
    path = tmp_path / "damaged.db"
    path.write_bytes(small_catalog.read_bytes())
    con = sqlite3.connect(path)
    root = con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'objects'").fetchone()[0]
    page = con.execute("PRAGMA page_size").fetchone()[0]
    con.close()
    with open(path, "r+b") as fh:  # the objects table's root page: what `catalog list` reads first
        fh.seek((root - 1) * page)
        fh.write(b"\x0d\x00\x00\xff\xff" + b"\xff" * 64)
    code, lines = run_cli(["--db", str(path), "catalog", "list"], capsys)
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"error: catalog {path} is damaged (database disk image is malformed)"), lines
    assert f"sqlite3 {path} .recover | sqlite3 {tmp_path / 'damaged-recovered.db'}" in lines[0]
    assert "restore" in lines[0] and "backup" in lines[0]


def test_an_undamaged_copy_still_lists(small_catalog: Path, tmp_path: Path, capsys) -> None:
    path = tmp_path / "fine.db"
    path.write_bytes(small_catalog.read_bytes())
    assert cli.main(["--db", str(path), "catalog", "list", "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)) == 40


def test_ctrl_c_in_compose_keeps_finished_scenes_and_says_so(tmp_path: Path) -> None:
    """The real orchestration and scene task (a fake worker): Ctrl-C after the second finished scene."""
    config = load_config(["quick"], values={"compose.seed": 100, "compose.split": "train"})
    pool, out = _pool(tmp_path), tmp_path / "out"
    runner = lambda task, _worker: run_scene_task(task, FakeWorker(task.spec, lambda s: "ok", []))  # noqa: E731
    seen: list[object] = []

    def on_outcome(outcome: object) -> None:
        seen.append(outcome)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with LocalExecutor(1, runner=runner, recycle_after=0, settle_ahead=False) as executor:
        with pytest.raises(StoppedByUser) as stopped:
            compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=tmp_path / "assets", n=5,
                           executor=executor, on_outcome=on_outcome)
    assert str(stopped.value) == "stopped by the user; 2 scenes finished and kept; rerun the same command to go on"
    kept = sorted(p.name for p in (out / "scenes").iterdir() if not p.name.startswith("."))
    assert len(kept) == 2 and all((out / "scenes" / k / "metadata.json").is_file() for k in kept)


@pytest.mark.parametrize("raised, line", [
    (StoppedByUser("stopped by the user; 3 scenes finished and kept; rerun the same command to go on"),
     "stopped by the user; 3 scenes finished and kept; rerun the same command to go on"),
    (KeyboardInterrupt(), "stopped by the user"),
])
def test_cli_turns_ctrl_c_into_one_line_and_exit_130(raised: BaseException, line: str, monkeypatch, capsys) -> None:
    tiny = typer.Typer()

    @tiny.command()
    def run() -> None:
        raise raised

    monkeypatch.setattr(cli, "app", tiny)
    code, lines = run_cli([], capsys)
    assert code == 130 and lines == [line]


def test_cli_turns_sigterm_into_one_line_and_exit_143(monkeypatch, capsys) -> None:
    """SIGTERM takes the Ctrl-C path (mixcount.stop_signals): compose's "N scenes finished and kept" line
    reads "stopped by SIGTERM; ..." and the code is 143, the shell's for SIGTERM."""
    import os
    import signal
    import time

    tiny = typer.Typer()

    @tiny.command()
    def run() -> None:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)  # the handler raises KeyboardInterrupt here
        except KeyboardInterrupt:
            raise StoppedByUser("stopped by the user; 1 scene finished and kept; rerun the same command to go on") from None

    monkeypatch.setattr(cli, "app", tiny)
    before = signal.getsignal(signal.SIGTERM)
    code, lines = run_cli([], capsys)
    assert code == 143 and lines == ["stopped by SIGTERM; 1 scene finished and kept; rerun the same command to go on"]
    assert signal.getsignal(signal.SIGTERM) is before  # the command's handler is gone with the command


def test_a_scene_finished_while_stopping_is_counted_as_kept(tmp_path: Path) -> None:
    """A SIGTERM reaches the driver alone: a scene still in flight can be completed by its worker thread while
    the run stops. The stop's line counts the scenes finished on disk, not only the outcomes read: here the
    third scene is complete before the stop is raised (the run reads two outcomes, then stops)."""
    import time

    config = load_config(["quick"], values={"compose.seed": 100, "compose.split": "train"})
    pool, out = _pool(tmp_path), tmp_path / "out"
    runner = lambda task, _worker: run_scene_task(task, FakeWorker(task.spec, lambda s: "ok", []))  # noqa: E731
    seen: list[object] = []

    def finished() -> list[str]:
        return sorted(p.name for p in (out / "scenes").iterdir()
                      if not p.name.startswith(".") and (p / "metadata.json").is_file())

    def on_outcome(outcome: object) -> None:
        seen.append(outcome)
        if len(seen) == 2:  # the third scene is in flight: let its thread finish it, then stop
            deadline = time.monotonic() + 60
            while len(finished()) < 3 and time.monotonic() < deadline:
                time.sleep(0.05)
            raise KeyboardInterrupt

    with LocalExecutor(2, runner=runner, recycle_after=0, settle_ahead=False) as executor:
        with pytest.raises(StoppedByUser) as stopped:
            compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=tmp_path / "assets", n=6,
                           executor=executor, on_outcome=on_outcome)
    assert len(finished()) == 3
    assert str(stopped.value) == "stopped by the user; 3 scenes finished and kept; rerun the same command to go on"
