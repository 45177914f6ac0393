"""Entry point of a long-lived bpy worker process: ``python -m mixcount.engine.worker_main``.

Protocol: one JSON object per line. The parent writes requests to the worker's stdin; the worker answers
each with one JSON line on its ORIGINAL stdout. Everything bpy / Cycles print (C-level stdout) is
redirected to stderr at start-up, so the protocol channel carries nothing else. The typed operations
(:mod:`mixcount.worker.contract`) travel as ``{"op": OP, "request": <request>.to_dict()}`` and are
answered ``{"ok": true, "result": <result>.to_dict(), "seconds": ...}``:

* ``scene``: SceneRequest -> SceneResult (:func:`mixcount.engine.scene_job.run_scene`)
* ``canonical``: CanonicalRequest -> CanonicalResult (:func:`mixcount.engine.canonical_render.render_object`)
* ``cache_meshes``: MeshCacheRequest -> MeshCacheResult
  (:func:`mixcount.engine.asset_meshes.cache_asset_meshes`)
* ``settle``: SceneRequest -> SettleResult (:func:`mixcount.engine.scene_job.settle_ahead`)
* ``rerender``: RerenderRequest -> SceneResult, ``devices``: DevicesRequest -> DevicesResult
  (:mod:`mixcount.engine.rerender_job`)

and two plain ones: ``{"op": "ping"}`` -> ``{"ok": true, "pid": ..., "tbb_concurrency": ...}``; ``{"op": "exit"}`` ->
``{"ok": true}`` and the process ends.

A Python error in a handler answers ``{"ok": false, "error", "traceback"}`` and the worker stays up for
the next request. The first line the worker writes is ``{"ready": true, "pid": ...}`` once bpy is imported.
:func:`main` takes the handler table, so another entry module can serve more ops with the same loop.

For a run that lasts days (docs/faults.md): ``faulthandler`` writes every thread's Python stack to the
log (stderr) on SIGSEGV / SIGFPE / SIGABRT / SIGBUS / SIGILL, and C-level stdout (bpy, Cycles) is made
unbuffered, so a crash's last output reaches the log. The worker dies with its parent
(:func:`die_with_parent`): ``PR_SET_PDEATHSIG`` = SIGKILL on Linux (the kernel kills it the moment the
parent's spawning thread, which lives as long as the parent, is gone), and everywhere a thread that
exits the process when its parent pid changes; a request is never started once the parent is gone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import faulthandler
import json
import os
import signal
import sys
import threading
import time
import traceback
from typing import Any, Callable, Mapping, Optional

from mixcount.task_memory import collected_when_grown

PARENT_ENV = "MIXCOUNT_PARENT_PID"  # set by mixcount.worker.client.BlenderWorker
THREADS_ENV = "MIXCOUNT_WORKER_THREADS"  # the CPU threads this worker's renders use (0 / unset: all)
PR_SET_PDEATHSIG = 1
WATCH_S = 0.5  # how often the watch thread looks at the parent pid
_IONBF = 2  # glibc's setvbuf mode "unbuffered"

Handler = Callable[[dict[str, Any]], dict[str, Any]]


def _typed(request_type: Any, run: Callable[[Any], Any]) -> Handler:
    """A handler that decodes ``req["request"]`` as ``request_type``, runs it and answers its result."""
    def handle(req: dict[str, Any]) -> dict[str, Any]:
        t0 = time.perf_counter()
        result = run(request_type.from_dict(req["request"]))
        return {"ok": True, "result": result.to_dict(), "seconds": round(time.perf_counter() - t0, 3)}
    return handle


def _scene(req: Any) -> Any:
    import dataclasses

    from mixcount.engine import devices
    from mixcount.engine.scene_job import run_scene

    device = devices.use(req.device)  # applied where the render settings are made (configure_common)
    result = run_scene(req)
    return dataclasses.replace(result, diagnostics=(*result.diagnostics, {"kind": "device", **device.to_dict()}))


def _canonical(req: Any) -> Any:
    from mixcount.engine.canonical_render import render_object

    return render_object(req)


def _cache_meshes(req: Any) -> Any:
    from mixcount.engine.asset_meshes import cache_asset_meshes

    return cache_asset_meshes(req)


def _settle(req: Any) -> Any:
    from mixcount.engine.scene_job import settle_ahead

    return settle_ahead(req)


def _rerender(req: Any) -> Any:
    from mixcount.engine.rerender_job import run_rerender

    return run_rerender(req)


def _devices(req: Any) -> Any:
    if req.setting is not None:  # compose's device check (mixcount.run.devices)
        from mixcount.engine import devices

        return devices.select(req.device, key=req.setting)
    from mixcount.engine.rerender_job import probe_devices

    return probe_devices(req)


def _handlers() -> dict[str, Handler]:
    from mixcount.worker.canonical_contract import CanonicalRequest
    from mixcount.worker.contract import MeshCacheRequest, SceneRequest, SettleResult
    from mixcount.worker.rerender_contract import DevicesRequest, RerenderRequest

    return {SceneRequest.OP: _typed(SceneRequest, _scene), CanonicalRequest.OP: _typed(CanonicalRequest, _canonical),
            MeshCacheRequest.OP: _typed(MeshCacheRequest, _cache_meshes),
            SettleResult.OP: _typed(SceneRequest, _settle),
            RerenderRequest.OP: _typed(RerenderRequest, _rerender), DevicesRequest.OP: _typed(DevicesRequest, _devices)}


HANDLERS: dict[str, Handler] = _handlers()


def _libc() -> Any:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name, use_errno=True) if name else None
    except OSError:  # pragma: no cover - no C library to load
        return None


def parent_gone(parent: Optional[int]) -> bool:
    """Whether the process that started this worker has died (this one was reparented)."""
    return parent is not None and os.getppid() != parent


def die_with_parent() -> Optional[int]:
    """Tie this process's life to its parent's (``MIXCOUNT_PARENT_PID``; None when unset, nothing is done):
    PR_SET_PDEATHSIG where the C library has prctl (Linux), then a daemon thread that ``os._exit`` s when the
    parent pid changes (every system; it needs the GIL, which a long C call may hold: PDEATHSIG does not).
    Exits at once when the parent is already gone. Returns the parent pid watched."""
    raw = os.environ.get(PARENT_ENV)
    if not raw:
        return None
    parent = int(raw)
    libc = _libc()
    if sys.platform.startswith("linux") and libc is not None:
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if parent_gone(parent):  # died before prctl took effect
        os._exit(3)

    def watch() -> None:
        while not parent_gone(parent):
            time.sleep(WATCH_S)
        sys.stderr.write(f"mixcount worker {os.getpid()}: parent {parent} is gone, exiting\n")
        os._exit(3)

    threading.Thread(target=watch, name="mixcount-parent-watch", daemon=True).start()
    return parent


def crash_reports_to_log() -> None:
    """faulthandler on stderr (the worker's log), every thread; C stdio's stdout (fd 1, redirected to the
    log) unbuffered, so what bpy / Cycles printed last before a crash is in the log."""
    faulthandler.enable(file=sys.stderr, all_threads=True)
    libc = _libc()
    if libc is None:
        return
    try:
        c_stdout = ctypes.c_void_p.in_dll(libc, "stdout")
        libc.setvbuf(c_stdout, None, _IONBF, 0)
    except (ValueError, AttributeError):  # pragma: no cover - a C library without a "stdout" symbol
        pass


def import_bpy(threads: int) -> None:
    """Import bpy with oneTBB sized to the ``threads`` CPU threads this worker renders with (0: all).

    oneTBB fixes its default concurrency once, from the process's CPU affinity mask, when Blender starts its
    task scheduler (at ``import bpy``; the bpy module takes no ``--threads``). A worker of 2 on 2 cores
    renders with 1 Cycles thread (``render.threads``), but Blender's TBB still starts a worker thread per
    core, and while Cycles runs that thread spins in ``sched_yield`` looking for work: measured on a
    1.2 M-face render with 1 thread, user 9.5 + system 7.8 CPU-s for 8.8 s of wall time, the whole second
    core burnt (docs/blender.md). So for the import the process is held to ``threads`` of its CPUs, then
    given all of them back: TBB keeps the concurrency it read, Cycles the threads it is told, and the other
    worker its core. Which CPUs hold the import follows the pid, so workers starting together (a Ray node's
    actors) do not all import on the first one."""
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if not 0 < threads < len(allowed):
        import bpy  # noqa: F401
        return
    first = os.getpid() % len(allowed)
    os.sched_setaffinity(0, [allowed[(first + k) % len(allowed)] for k in range(threads)])
    try:
        import bpy  # noqa: F401,F811
    finally:
        os.sched_setaffinity(0, allowed)


def tbb_concurrency() -> Optional[int]:
    """The default concurrency of the oneTBB that bpy loaded (what :func:`import_bpy` sized), read from
    libtbb's exported ``max_concurrency``; None where the library or the symbol cannot be found."""
    try:
        lib = ctypes.CDLL("libtbb.so.12", mode=os.RTLD_NOLOAD | os.RTLD_LAZY)  # bpy's copy, already loaded
        fn = lib._ZN3tbb6detail2r115max_concurrencyEPKNS0_2d115task_arena_baseE  # r1::max_concurrency(nullptr)
    except (OSError, AttributeError):
        return None
    fn.restype, fn.argtypes = ctypes.c_int, [ctypes.c_void_p]
    return int(fn(None))


def worker_threads() -> int:
    """The thread count the parent gave this worker (:data:`THREADS_ENV`), 0 when unset or unreadable."""
    try:
        return max(0, int(os.environ.get(THREADS_ENV, "0")))
    except ValueError:
        return 0


def main(handlers: Optional[Mapping[str, Handler]] = None) -> int:
    handlers = HANDLERS if handlers is None else handlers
    parent = die_with_parent()
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # bpy and Cycles print to fd 1: keep the protocol channel clean
    sys.stdout = sys.stderr
    crash_reports_to_log()

    def reply(obj: dict) -> None:
        proto.write(json.dumps(obj) + "\n")
        proto.flush()

    import_bpy(worker_threads())  # import once: the slow part of a worker's start
    from pxr import Usd, UsdGeom, UsdLux, UsdPhysics, UsdShade  # noqa: F401

    Usd.Stage.CreateInMemory()  # USD's plugin registry loads here, once, not inside the first scene
    faulthandler.enable(file=sys.stderr, all_threads=True)  # again: in case an import installed its own handler

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
        if parent_gone(parent):  # the run that asked is gone: write nothing into its folder
            break
        if op == "exit":
            reply({"ok": True})
            break
        if op == "ping":
            reply({"ok": True, "pid": os.getpid(), "tbb_concurrency": tbb_concurrency()})
            continue
        handler = handlers.get(op)
        if handler is None:
            reply({"ok": False, "error": f"unknown op {op!r}"})
            continue
        # What a request built in reference cycles (the glTF importer's objects and arrays) is freed once the
        # worker has grown enough, before the answer goes: without it a canonical-render worker grew ~45 MB
        # with each 1.2 M-face capture (799 -> 1,202 MB after 6), docs/performance.md.
        with collected_when_grown():
            try:
                answer = handler(req)
            except Exception as exc:  # the request fails, the worker lives on
                from mixcount.errors import MixcountError  # a user's error (a missing file): its line, no traceback

                answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}",
                          "traceback": "" if isinstance(exc, MixcountError) else traceback.format_exc()}
        reply(answer)
        sys.stderr.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
