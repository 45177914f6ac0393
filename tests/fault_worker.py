"""A bpy worker entry for tests only: ``python -m tests.fault_worker`` serves the production handlers of
:mod:`mixcount.blender.worker_main` plus faults the tests of timeouts and crashes need:

* ``{"op": "sleep", "seconds": s}`` - a hung request;
* a ``canonical`` job with ``"_test_hang_s": s`` hangs, one with ``"_test_crash": code`` kills the
  process mid-job (``os._exit``); any other job renders normally.

Tests select it with ``monkeypatch.setattr("mixcount.blender.worker.WORKER_MODULE", "tests.fault_worker")``.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from mixcount.blender import worker_main


def sleep(req: dict[str, Any]) -> dict[str, Any]:
    time.sleep(float(req["seconds"]))
    return {"ok": True}


def canonical(req: dict[str, Any]) -> dict[str, Any]:
    job = req["job"]
    if job.get("_test_hang_s"):
        time.sleep(float(job["_test_hang_s"]))
    if job.get("_test_crash"):
        os._exit(int(job["_test_crash"]))
    return worker_main.handle_canonical(req)


if __name__ == "__main__":
    sys.exit(worker_main.main({**worker_main.HANDLERS, "sleep": sleep, "canonical": canonical}))
