"""Entry point of a long-lived bpy worker process: ``python -m mixcount.blender.worker_main``.

Protocol: one JSON object per line. The parent writes requests to the worker's stdin; the worker answers
each with one JSON line on its ORIGINAL stdout. Everything bpy / Cycles print (C-level stdout) is
redirected to stderr at start-up, so the protocol channel carries nothing else. Requests:

* ``{"op": "ping"}`` -> ``{"ok": true, "pid": ...}``
* ``{"op": "scene", "stage": ..., "out_dir": ..., ...}`` -> ``{"ok": true, "status": ..., "result": path}``
  (see :func:`mixcount.blender.scene_job.run_scene`); a Python error answers ``{"ok": false, "error",
  "traceback"}`` and the worker stays up for the next scene.
* ``{"op": "sleep", "seconds": s}`` (tests of the per-scene timeout), ``{"op": "exit"}``.

The first line the worker writes is ``{"ready": true, "pid": ...}`` once bpy is imported.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback


def main() -> int:
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # bpy and Cycles print to fd 1: keep the protocol channel clean
    sys.stdout = sys.stderr

    def reply(obj: dict) -> None:
        proto.write(json.dumps(obj) + "\n")
        proto.flush()

    import bpy  # noqa: F401  (import once: the slow part of a worker's start)

    from mixcount.blender.scene_job import run_scene

    reply({"ready": True, "pid": os.getpid()})
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        try:
            req = json.loads(line)
        except json.JSONDecodeError as exc:
            reply({"ok": False, "error": f"bad request: {exc}"})
            continue
        op = req.get("op")
        if op == "exit":
            reply({"ok": True})
            break
        if op == "ping":
            reply({"ok": True, "pid": os.getpid()})
            continue
        if op == "sleep":
            time.sleep(float(req.get("seconds", 1.0)))
            reply({"ok": True})
            continue
        if op == "scene":
            t0 = time.perf_counter()
            try:
                result = run_scene(req)
                reply({"ok": True, "status": result["status"], "result": os.path.join(req["out_dir"], "worker.json"),
                       "seconds": round(time.perf_counter() - t0, 3)})
            except Exception as exc:  # the scene fails, the worker lives on
                reply({"ok": False, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()})
            sys.stderr.flush()
            continue
        reply({"ok": False, "error": f"unknown op {op!r}"})
    return 0


if __name__ == "__main__":
    sys.exit(main())
