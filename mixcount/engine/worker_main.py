"""Entry point of a long-lived bpy worker process: ``python -m mixcount.engine.worker_main``.

Protocol: one JSON object per line. The parent writes requests to the worker's stdin; the worker answers
each with one JSON line on its ORIGINAL stdout. Everything bpy / Cycles print (C-level stdout) is
redirected to stderr at start-up, so the protocol channel carries nothing else. The typed operations
(:mod:`mixcount.worker.contract`) travel as ``{"op": OP, "request": <request>.to_dict()}`` and are
answered ``{"ok": true, "result": <result>.to_dict(), "seconds": ...}``:

* ``scene``: SceneRequest -> SceneResult (:func:`mixcount.engine.scene_job.run_scene`)
* ``canonical``: CanonicalRequest -> CanonicalResult (:func:`mixcount.engine.canonical_render.render_object`)
* ``cache_meshes``: MeshCacheRequest -> MeshCacheResult
  (:func:`mixcount.engine.scene_build.cache_asset_meshes`)
* ``settle``: SceneRequest -> SettleResult (:func:`mixcount.engine.scene_job.settle_ahead`)
* ``rerender``: RerenderRequest -> SceneResult, ``devices``: DevicesRequest -> DevicesResult
  (:mod:`mixcount.engine.rerender_job`)

and two plain ones: ``{"op": "ping"}`` -> ``{"ok": true, "pid": ...}``; ``{"op": "exit"}`` ->
``{"ok": true}`` and the process ends.

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


def _typed(request_type: Any, run: Callable[[Any], Any]) -> Handler:
    """A handler that decodes ``req["request"]`` as ``request_type``, runs it and answers its result."""
    def handle(req: dict[str, Any]) -> dict[str, Any]:
        t0 = time.perf_counter()
        result = run(request_type.from_dict(req["request"]))
        return {"ok": True, "result": result.to_dict(), "seconds": round(time.perf_counter() - t0, 3)}
    return handle


def _scene(req: Any) -> Any:
    from mixcount.engine.scene_job import run_scene

    return run_scene(req)


def _canonical(req: Any) -> Any:
    from mixcount.engine.canonical_render import render_object

    return render_object(req)


def _cache_meshes(req: Any) -> Any:
    from mixcount.engine.scene_build import cache_asset_meshes

    return cache_asset_meshes(req)


def _settle(req: Any) -> Any:
    from mixcount.engine.scene_job import settle_ahead

    return settle_ahead(req)


def _rerender(req: Any) -> Any:
    from mixcount.engine.rerender_job import run_rerender

    return run_rerender(req)


def _devices(req: Any) -> Any:
    from mixcount.engine.rerender_job import probe_devices

    return probe_devices(req)


def _handlers() -> dict[str, Handler]:
    from mixcount.worker.contract import (
        CanonicalRequest,
        DevicesRequest,
        MeshCacheRequest,
        RerenderRequest,
        SceneRequest,
        SettleResult,
    )

    return {SceneRequest.OP: _typed(SceneRequest, _scene), CanonicalRequest.OP: _typed(CanonicalRequest, _canonical),
            MeshCacheRequest.OP: _typed(MeshCacheRequest, _cache_meshes),
            SettleResult.OP: _typed(SceneRequest, _settle),
            RerenderRequest.OP: _typed(RerenderRequest, _rerender), DevicesRequest.OP: _typed(DevicesRequest, _devices)}


HANDLERS: dict[str, Handler] = _handlers()


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
