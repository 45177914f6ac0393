"""Worker entry point: ``python -m mixcount.blender.canonical_job JOBS.json RESULTS.jsonl``.

Runs in its own process so bpy starts once per batch and never in the CLI process. ``JOBS.json`` is a
list of job dicts (see :func:`mixcount.blender.canonical.render_object`, plus ``key``). For each job the
worker appends ``{"key", "event": "start"}`` and then ``{"key", "event": "done", "views": [...]}`` or
``{"key", "event": "failed", "error": "..."}`` to ``RESULTS.jsonl``, flushed line by line, so the parent
can see progress, detect a hang (a start without an end) and restart the batch after the last job.
A failure of one object is reported and the batch goes on.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any, TextIO


def _emit(fh: TextIO, record: dict[str, Any]) -> None:
    fh.write(json.dumps(record, sort_keys=True) + "\n")
    fh.flush()
    os.fsync(fh.fileno())


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python -m mixcount.blender.canonical_job JOBS.json RESULTS.jsonl", file=sys.stderr)
        return 2
    jobs = json.loads(Path(args[0]).read_text())
    from mixcount.blender.canonical import render_object  # imports bpy lazily, inside the worker

    with open(args[1], "a", encoding="utf-8") as fh:
        for job in jobs:
            key = job["key"]
            _emit(fh, {"key": key, "event": "start", "pid": os.getpid()})
            try:
                if job.get("_test_hang_s"):  # test hook: simulate a hung render (tests/test_renders.py)
                    time.sleep(float(job["_test_hang_s"]))
                if job.get("_test_crash"):  # test hook: simulate a worker dying mid-object
                    os._exit(int(job["_test_crash"]))
                result = render_object(job)
            except Exception as exc:  # one object's failure is recorded; the batch goes on
                msg = f"{type(exc).__name__}: {exc}".strip()
                traceback.print_exc(file=sys.stderr)
                _emit(fh, {"key": key, "event": "failed", "error": msg[:2000]})
                continue
            _emit(fh, {"key": key, "event": "done", **result})
    return 0


if __name__ == "__main__":
    sys.exit(main())
