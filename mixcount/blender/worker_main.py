"""Entry point of a long-lived bpy worker process: ``python -m mixcount.blender.worker_main``.

Protocol: one JSON object per line. The parent writes requests to the worker's stdin; the worker answers
each with one JSON line on its ORIGINAL stdout. Everything bpy / Cycles print (C-level stdout) is
redirected to stderr at start-up, so the protocol channel carries nothing else. Requests:

* ``{"op": "ping"}`` -> ``{"ok": true, "pid": ...}``
* ``{"op": "scene", "request": SceneRequest}`` -> ``{"ok": true, "status": ..., "result": path of
  worker.json}`` (the :class:`~mixcount.blender.contract.SceneResult`, see
  :func:`mixcount.blender.scene_job.run_scene`)
* ``{"op": "canonical", "job": {...}}`` -> ``{"ok": true, "views": [...]}`` (one catalog object's
  canonical renders, see :func:`mixcount.blender.canonical.render_object`)
* ``{"op": "cache_meshes", "assets": [paths], "mode": "zstd"}`` -> ``{"ok": true, "assets": {name:
  "hit" | "written" | why not}}`` (each converted asset's .blend mesh cache made ahead of the scenes, see
  :func:`mixcount.blender.scene_job.cache_asset_meshes`)
* ``{"op": "exit"}`` -> ``{"ok": true}`` and the process ends.

A Python error in a handler answers ``{"ok": false, "error", "traceback"}`` and the worker stays up for
the next request. The first line the worker writes is ``{"ready": true, "pid": ...}`` once bpy is imported.
:func:`main` takes the handler table, so another entry module can serve more ops with the same loop.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from typing import Any, Callable, Mapping, Optional

Handler = Callable[[dict[str, Any]], dict[str, Any]]


def handle_scene(req: dict[str, Any]) -> dict[str, Any]:
    from mixcount.blender.contract import SceneRequest
    from mixcount.blender.scene_job import run_scene

    scene_req = SceneRequest.from_dict(req["request"])
    t0 = time.perf_counter()
    result = run_scene(scene_req)
    return {"ok": True, "status": result.status, "result": os.path.join(scene_req.out_dir, "worker.json"),
            "seconds": round(time.perf_counter() - t0, 3)}


def handle_canonical(req: dict[str, Any]) -> dict[str, Any]:
    from mixcount.blender.canonical import render_object

    return {"ok": True, **render_object(req["job"])}


def handle_cache_meshes(req: dict[str, Any]) -> dict[str, Any]:
    from mixcount.blender.scene_job import cache_asset_meshes

    return {"ok": True, "assets": cache_asset_meshes(req["assets"], str(req["mode"]))}


HANDLERS: dict[str, Handler] = {"scene": handle_scene, "canonical": handle_canonical,
                                "cache_meshes": handle_cache_meshes}


def main(handlers: Optional[Mapping[str, Handler]] = None) -> int:
    handlers = HANDLERS if handlers is None else handlers
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # bpy and Cycles print to fd 1: keep the protocol channel clean
    sys.stdout = sys.stderr

    def reply(obj: dict) -> None:
        proto.write(json.dumps(obj) + "\n")
        proto.flush()

    import bpy  # noqa: F401  (import once: the slow part of a worker's start)
    from pxr import Usd, UsdGeom, UsdLux, UsdPhysics, UsdShade  # noqa: F401

    Usd.Stage.CreateInMemory()  # USD's plugin registry loads here, once, not inside the first scene

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
        handler = handlers.get(op)
        if handler is None:
            reply({"ok": False, "error": f"unknown op {op!r}"})
            continue
        try:
            reply(handler(req))
        except Exception as exc:  # the request fails, the worker lives on
            reply({"ok": False, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()})
        sys.stderr.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
