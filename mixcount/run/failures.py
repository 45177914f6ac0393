"""The failure log of a compose output folder: ``OUT/logs/failures.jsonl``, one JSON line per failed scene.

A run that lasts days must explain every scene it lost. Each line keeps what reproduces and explains the
failure: scene id and seed (``mixcount compose --n 1 --seed S`` draws the same scene again), the cause
(:func:`mixcount.run.faults.failure_cause`), a dead worker's exit code / signal and its kept log, the last
lines of that log (faulthandler's report of a crash among them) and the first line of the error. A failed
seed is not rejected: a rerun draws it again, and the line stays as history (``resolved`` in ``stats``
when its scene now exists). ``mixcount stats`` counts the lines by cause (:func:`mixcount.evaluate.run_health.failures_by_cause`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Optional

from mixcount.evaluate.run_health import FAILURES_FILE, failures_by_cause, read_failures

__all__ = ["FAILURES_FILE", "append_failure", "failure_record", "failures_by_cause", "read_failures"]


def failure_record(outcome: Any, *, split: str, cause: str) -> dict[str, Any]:
    """The failure line of one failed :class:`~mixcount.run.scene_task.SceneOutcome`."""
    from mixcount.worker.client import exit_words, last_lines

    error = outcome.error or ""
    tail = error.split("last lines:\n", 1)[1] if "last lines:\n" in error else ""
    rec: dict[str, Any] = {
        "scene_id": outcome.scene_id, "seed": outcome.seed, "cause": cause, "error": error.splitlines()[0][:500] if error else "",
        "exit_code": outcome.exit_code, "exit": exit_words(outcome.exit_code) if outcome.exit_code is not None else None,
        "log": outcome.log, "log_tail": last_lines(tail), "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "reproduce": f"mixcount compose --n 1 --seed {outcome.seed} --split {split}",
    }
    return rec


def append_failure(out_dir: Path, record: dict[str, Any]) -> Optional[Path]:
    """Append one line to ``OUT/logs/failures.jsonl``; None when it cannot be written (a full disk: the run
    stops for that anyway, and says so)."""
    path = Path(out_dir) / "logs" / FAILURES_FILE
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "a") as f:
            f.write(json.dumps(record) + "\n")
    except OSError:
        return None
    return path
