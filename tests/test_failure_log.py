"""The failure log's causes and lines (no bpy): what ``mixcount stats`` counts a failed scene under, and
the line that reproduces it. The real crash path (a SIGSEGV of a bpy worker mid-scene) is
tests/test_blender_worker.py::test_worker_segfault_mid_scene_is_explained_and_the_next_scene_composed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mixcount.run.failures import append_failure, failure_record, failures_by_cause, read_failures
from mixcount.run.faults import failure_cause
from mixcount.run.scene_task import FAILED, SceneOutcome


@pytest.mark.parametrize("error, code, cause", [
    ("WorkerDied: worker0: worker died (SIGSEGV, exit code -11) while handling 'scene'", -11, "worker SIGSEGV"),
    ("WorkerDied: worker0: worker died (SIGKILL, exit code -9) while handling 'scene'", -9, "worker SIGKILL"),
    ("WorkerDied: worker0: worker died (exit code 3) while handling 'scene'", 3, "worker exit 3"),
    ("WorkerDied: worker0: timed out after 900 s while handling 'scene'; worker killed", None, "timeout"),
    ("OSError: [Errno 28] No space left on device: '/out/scenes/x'", None, "storage"),
    ("sampling: no container fits", None, "sampling"),
    ("RenderError: worker0: scene failed: ValueError: bad stage\nTraceback ...", None, "scene error: ValueError"),
    ("KeyError: 'x'", None, "error: KeyError"),
    ("", None, "unknown"),
])
def test_failure_cause(error: str, code: int | None, cause: str) -> None:
    assert failure_cause(error, code) == cause


def test_failure_line_keeps_the_tail_the_seed_and_how_to_reproduce(tmp_path: Path) -> None:
    error = ("WorkerDied: worker0: worker died (SIGSEGV, exit code -11) while handling 'scene'; its log is kept as "
             "/o/logs/w.log; last lines:\nFatal Python error: Segmentation fault\n  File \"x.py\", line 3 in render")
    outcome = SceneOutcome("scene_000042", 42, FAILED, 1.0, error=error, exit_code=-11, log="/o/logs/w.log")
    rec = failure_record(outcome, split="val", cause=failure_cause(error, -11))
    assert rec["log_tail"] == "Fatal Python error: Segmentation fault\n  File \"x.py\", line 3 in render"
    assert rec["error"].startswith("WorkerDied: worker0: worker died (SIGSEGV") and "\n" not in rec["error"]
    assert (rec["exit"], rec["log"], rec["reproduce"]) == ("SIGSEGV, exit code -11", "/o/logs/w.log",
                                                           "mixcount compose --n 1 --seed 42 --split val")
    assert append_failure(tmp_path, rec) == tmp_path / "logs" / "failures.jsonl"
    with open(tmp_path / "logs" / "failures.jsonl", "a") as f:
        f.write('{"scene_id": "scene_0')  # a line cut by a killed run
    (tmp_path / "scenes" / "scene_000042").mkdir(parents=True)
    (tmp_path / "scenes" / "scene_000042" / "metadata.json").write_text(json.dumps({"complete": True}))
    assert [r["scene_id"] for r in read_failures(tmp_path)] == ["scene_000042"]
    counted = failures_by_cause(tmp_path)
    assert counted["by_cause"] == {"worker SIGSEGV": 1} and counted["resolved"] == 1


def test_compose_summary_names_the_causes_and_the_failure_log(tmp_path: Path) -> None:
    from mixcount.commands.compose import _compose_lines
    from mixcount.run.compose import ComposeSummary

    summary = ComposeSummary(requested=3, written=3, failed=3, failures=[
        {"scene_id": "scene_000001", "cause": "worker SIGSEGV"}, {"scene_id": "scene_000002", "cause": "timeout"},
        {"scene_id": "scene_000004", "cause": "worker SIGSEGV"}])
    lines = _compose_lines(summary, tmp_path, merge=True)
    assert lines[0].startswith("wrote 3 new scene(s) (0 already there, 3 failed")
    assert lines[1] == ("failed scenes by cause: worker SIGSEGV 2, timeout 1 (seeds, signals and kept logs: "
                        f"{tmp_path / 'logs' / 'failures.jsonl'})")


def test_a_long_faulthandler_report_keeps_its_header_in_the_tail() -> None:
    """faulthandler's stacks of every thread run past the tail's line count: the tail then starts at the
    report's header (what crashed), each line cut, instead of showing only the last threads' frames."""
    from mixcount.worker.client import LINE_CHARS, TAIL_LINES, last_lines

    threads = [f'  File "/x/thread{k}.py", line {k} in run' for k in range(3 * TAIL_LINES)]
    log = "\n".join(["scene 7: settling", "Fatal Python error: Segmentation fault", "",
                     "Current thread 0x1 (most recent call first):", *threads,
                     "Extension modules: " + ", ".join(f"mod{k}" for k in range(400))])
    tail = last_lines(log).splitlines()
    assert tail[0] == "Fatal Python error: Segmentation fault" and len(tail) == TAIL_LINES
    assert "Current thread" in tail[1]
    short = last_lines("a\nb\nFatal Python error: Aborted\nc")  # the whole report fits: the last lines
    assert short.splitlines() == ["a", "b", "Fatal Python error: Aborted", "c"]
    assert all(len(ln) <= LINE_CHARS for ln in last_lines("x" * 5000).splitlines())
