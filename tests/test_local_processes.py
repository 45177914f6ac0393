"""`catalog filter` on every core of this machine (issue 69): :class:`LocalProcesses` keeps the cluster's
contract (results in order, a dead worker told from the others), and the filter's flags are those of one
process whatever ``[filter] workers`` is."""

from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import weakref
from pathlib import Path

import pytest

from mixcount.catalog.step_executor import InThisProcess, LocalProcesses, TaskFailed

ROOT = Path(__file__).resolve().parent.parent
MIX = ROOT / ".venv" / "bin" / "mixcount"


def square_or_die(x: int) -> int:
    """x squared; 13 kills its own worker process as a segfault would."""
    if x == 13:
        os.kill(os.getpid(), signal.SIGSEGV)
    return x * x


class _Capture:
    """Stands for one object's loaded mesh: it refers to itself, as a trimesh mesh and its caches do."""

    def __init__(self) -> None:
        self.me = self
        self.data = b"\x01" * (300 << 20)  # resident: over the growth that makes a worker collect


_LOADED: list[weakref.ref] = []


def load_one(_k: int) -> tuple[int, int]:
    """(the pid, how many captures of earlier tasks in this process are still alive), then one more capture
    left behind in a cycle that only a full collection frees (``gc.collect(1)`` moves it to the oldest
    generation while it is still referred to, as a task's many allocations do)."""
    alive = sum(1 for r in _LOADED if r() is not None)
    capture = _Capture()
    _LOADED.append(weakref.ref(capture))
    gc.collect(1)
    return os.getpid(), alive


@pytest.mark.parametrize("executor", ["local processes", "this process"])
def test_a_worker_keeps_nothing_of_one_task_when_it_takes_the_next(executor: str) -> None:
    """What a task left in reference cycles is freed before the worker's next task: a worker's memory is one
    object's, however many objects it analyses (``run_and_collect``; without it the sixth task found all five earlier ones alive)."""
    _LOADED.clear()
    with (LocalProcesses(1) if executor == "local processes" else InThisProcess()) as pool:
        got = list(pool.map(load_one, [(k,) for k in range(6)]))
    assert len({pid for pid, _ in got}) == 1  # one worker took every task
    assert [alive for _, alive in got] == [0] * 6


def test_a_worker_collects_only_once_it_has_grown(monkeypatch: pytest.MonkeyPatch) -> None:
    """A full collection costs ~0.1 s in a worker holding its parent's objects, more than a light object's
    task: it runs when the process grew by the margin since the last one, not after every task. The resident
    sizes are given (a process's free heap makes a real allocation's growth unpredictable); the real path
    is the two tests above."""
    from mixcount import task_memory
    from mixcount.task_memory import collected_when_grown

    # MB: before task 1, after it, before task 2, after it, after the collection
    sizes = iter([500 << 20, 550 << 20, 555 << 20, 560 << 20, 500 << 20])
    monkeypatch.setattr(task_memory, "resident_bytes", lambda: next(sizes))
    monkeypatch.setattr(task_memory, "_floor", None)  # as a fresh worker
    collections = gc.get_stats()[2]["collections"]
    with collected_when_grown(growth_mb=100):  # grown 50 MB: no collection
        pass
    assert gc.get_stats()[2]["collections"] == collections
    with collected_when_grown(growth_mb=55):  # grown 60 MB since the start: one collection
        pass
    assert gc.get_stats()[2]["collections"] == collections + 1
    assert task_memory._floor == 500 << 20  # measured again after it
    # the process returned memory since (a freed buffer): growth counts from where it is now, not the old floor
    sizes = iter([200 << 20, 350 << 20, 210 << 20])  # before task 3, after it, after the collection
    with collected_when_grown(growth_mb=100):  # 350 is under 500 + 100, but 150 MB over 200: one collection
        pass
    assert gc.get_stats()[2]["collections"] == collections + 2
    assert task_memory._floor == 210 << 20


def test_results_come_back_in_order_and_a_dead_worker_is_one_failure() -> None:
    with LocalProcesses(2) as pool:
        assert pool.cpus() == 2
        assert pool.put({"a": 1}) == {"a": 1}
        assert list(pool.map(square_or_die, [(k,) for k in range(8)])) == [k * k for k in range(8)]
        got = list(pool.map(square_or_die, [(k,) for k in (11, 12, 13, 14, 15)]))
        assert [g for g in got if not isinstance(g, TaskFailed)] == [121, 144, 196, 225]
        assert isinstance(got[2], TaskFailed) and "died" in got[2].error
        # the broken pool was replaced: the next map works as before
        assert list(pool.map(square_or_die, [(3,), (4,)])) == [9, 16]
        # a task that raises is one failure with its reason, as a Ray task's is; the others come back
        got = list(pool.map(square_or_die, [(2,), ("x",), (5,)]))
        assert got[0] == 4 and got[2] == 25
        assert isinstance(got[1], TaskFailed) and got[1].error.startswith("TypeError:"), got[1]


def _catalog(db: Path, *folders: Path) -> list[dict]:
    """``catalog list --json`` with the catalog folders (``folders``: the copy's original too) as ``DB``."""
    out = subprocess.run([str(MIX), "--db", str(db), "catalog", "list", "--json"], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout
    for folder in (db.parent, *folders):
        out = out.replace(str(folder), "DB")
    return [{k: v for k, v in o.items() if k not in ("created_at", "updated_at", "ingest_run_id")} for o in json.loads(out)]


@pytest.mark.skipif(not MIX.exists(), reason="needs the project's .venv (make setup)")
def test_filter_flags_are_the_same_with_one_process_and_with_two(tmp_path: Path) -> None:
    from mixcount.demo.library import generate_demo_library

    lib = tmp_path / "lib"
    generate_demo_library(lib, seed=3, n_objects=14)
    opts = ["--config", "configs/quick.toml", "--set", "canonical_render.resolution=48",
            "--set", "canonical_render.samples=1"]
    first = tmp_path / "one" / "catalog.db"
    first.parent.mkdir()
    for args in (["catalog", "ingest", str(lib)], ["catalog", "render"]):
        subprocess.run([str(MIX), "--db", str(first), *opts, *args], check=True, capture_output=True, cwd=ROOT)
    second = tmp_path / "two" / "catalog.db"
    subprocess.run(["cp", "-r", str(first.parent), str(second.parent)], check=True)
    summaries = []
    for db, workers in ((first, 1), (second, 2)):
        got = subprocess.run([str(MIX), "--db", str(db), *opts, "--set", f"filter.workers={workers}", "catalog", "filter"],
                             capture_output=True, text=True, cwd=ROOT)
        assert got.returncode == 0, got.stderr
        summaries.append(got.stdout.splitlines()[0])
        # progress on stderr (plain lines: not a terminal) for each phase, whichever executor ran it
        for phase in ("filter: descriptors: ", "filter: primitive fits: ", "filter: pair figures: "):
            assert phase in got.stderr, (workers, got.stderr[-2000:])
    assert summaries[0] == summaries[1]
    assert "candidate pairs compared" in summaries[0]
    one, two = _catalog(first), _catalog(second, first.parent)  # the copy keeps the paths of the first
    assert sum(len(o["flags"]) for o in one) > 10  # the library's traps were found: something to compare
    assert one == two


class StoppedAfterOneTask:
    """A cluster whose run is stopped (Ctrl-C) after its first pair-figures task came back: stands for a
    filter interrupted an hour into its alignments (the real tasks run in the test above)."""

    def __init__(self) -> None:
        self.known_sent: list[dict] = []

    def cpus(self) -> int:
        return 1

    def put(self, value: dict) -> dict:
        self.known_sent.append(dict(value))
        return value

    def map(self, fn, args):  # noqa: ANN001, ANN201 - the cluster contract
        yield {"pair-figure-a": 0.25}
        raise KeyboardInterrupt


def test_a_stopped_filter_keeps_the_figures_it_had(tmp_path: Path) -> None:
    from types import SimpleNamespace

    from mixcount.config import load_config
    from mixcount.curation.finding.catalog_filter import figures_in_parallel
    from mixcount.curation.finding.filter_items import Item, LayoutCache

    th = load_config().filter
    pairs = [(Item(SimpleNamespace(id=i)), Item(SimpleNamespace(id=i + 1))) for i in range(3)]  # type: ignore[arg-type]
    path = tmp_path / "layouts.json"
    with pytest.raises(KeyboardInterrupt):
        figures_in_parallel(StoppedAfterOneTask(), th, LayoutCache(path), pairs)
    assert json.loads(path.read_text()) == {"pair-figure-a": 0.25}
    again = StoppedAfterOneTask()
    with pytest.raises(KeyboardInterrupt):
        figures_in_parallel(again, th, LayoutCache(path), pairs)
    assert again.known_sent[-1] == {"pair-figure-a": 0.25}  # the rerun's tasks start from what was kept
