"""Settle-ahead, the worker side: a render worker plus a companion bpy process that settles the NEXT scene
while the current one renders (``compose.settle_ahead``; the run side that writes the next stage ahead is
:mod:`mixcount.run.staging_ahead`, the engine side the ``settle`` op of :mod:`mixcount.engine.scene_job`).
Both processes are plain :class:`~mixcount.worker.client.BlenderWorker` s driven through their public
:meth:`~mixcount.worker.client.BlenderWorker.post` / :meth:`~mixcount.worker.client.BlenderWorker.answer`.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional

from mixcount.errors import RenderError
from mixcount.worker.canonical_contract import CanonicalRequest, CanonicalResult
from mixcount.worker.client import STARTUP_TIMEOUT_S, BlenderWorker
from mixcount.worker.contract import MeshCacheRequest, MeshCacheResult, SceneRequest, SceneResult, SettleResult


class SettleAheadWorker:
    """A render worker with a companion bpy process that settles the NEXT scene while this one renders.

    Bullet steps on one thread, and a heavy container heap settles for seconds (docs/performance.md): run
    beside a render that uses every core, it costs that render about half its own time instead of all of
    it. :meth:`begin_settle` sends the next scene's stage to the companion (``settle`` op, nothing waits);
    :meth:`run_scene_job` of that stage collects its ``settled.json`` and lets the render worker apply the
    poses instead of simulating. The poses are the ones the render worker would have simulated (same code,
    same stage; tests/test_settle_ahead.py compares the outputs). When the companion fails, crashes or
    overruns, the diagnostic is logged and the render worker settles the scene itself: nothing is lost.
    Everything else (canonical renders, mesh caches, plain requests) goes to the render worker.
    """

    def __init__(self, *, name: str = "worker", log_dir: Optional[Path] = None, python: str = sys.executable,
                 startup_timeout: float = STARTUP_TIMEOUT_S, cpu_threads: int = 0) -> None:
        self.render = BlenderWorker(name=name, log_dir=log_dir, python=python, startup_timeout=startup_timeout,
                                    cpu_threads=cpu_threads)
        # Bullet steps on one thread: the companion's TBB needs no more, whatever the render uses
        self.settler = BlenderWorker(name=f"{name}-settle", log_dir=log_dir, python=python,
                                     startup_timeout=startup_timeout, cpu_threads=1)
        self.name = name
        self._pending: Optional[str] = None  # the stage whose settle is in flight in the companion
        # begin_settle (the pool's look-ahead thread) waits here until the settle in flight is collected
        self._turn = threading.Condition()
        self._closed = False
        self.settled_ahead = 0  # scenes rendered from the companion's poses
        self.settle_failures: list[str] = []  # why a settle ahead was not used (the scene settled here)

    @property
    def pid(self) -> Optional[int]:
        return self.render.pid

    def alive(self) -> bool:
        return self.render.alive()

    def begin_settle(self, req: SceneRequest) -> bool:
        """Start settling ``req``'s stage in the companion; returns once it is sent (after the settle in
        flight, if any, has been collected by :meth:`run_scene_job`). False when this worker was closed or
        the companion cannot start: the scene then settles in the render worker."""
        with self._turn:
            self._turn.wait_for(lambda: self._pending is None or self._closed)
            if self._closed:
                return False
        try:
            self.settler.start()  # outside the lock: bpy's start-up must not hold up run_scene_job
        except RenderError as exc:
            self.settle_failures.append(str(exc))
            return False
        with self._turn:
            if self._closed:  # closed while the companion started: it would be left running
                self.settler.kill()
                return False
            try:
                self.settler.post({"op": SettleResult.OP, "request": req.to_dict()})
            except RenderError as exc:
                self.settle_failures.append(str(exc))
                return False
            self._pending = req.stage
            return True

    def _collect(self, stage: str, timeout: float) -> Optional[SettleResult]:
        """The companion's answer when it is settling ``stage`` (None, with the reason recorded, when
        that fails; None at once when it settles another stage or nothing)."""
        with self._turn:
            if self._pending != stage:
                return None
            try:
                answer = self.settler.answer(timeout, "settling ahead")
            except RenderError as exc:
                self.settle_failures.append(str(exc))
                return None
            finally:
                self._pending = None
                self._turn.notify_all()
        if not answer.get("ok"):
            self.settle_failures.append(f"{answer.get('error')}")
            return None
        return SettleResult.from_dict(answer["result"])

    def run_scene_job(self, req: SceneRequest, *, timeout: float) -> SceneResult:
        """Run one scene with the companion's poses when it settled this stage, else settling it here."""
        ahead = self._collect(req.stage, timeout)
        if ahead is not None:
            req = replace(req, settled_poses_file=ahead.poses_file)
            self.settled_ahead += 1
        return self.render.run_scene_job(req, timeout=timeout)

    def render_canonical(self, req: CanonicalRequest, *, timeout: float) -> CanonicalResult:
        return self.render.render_canonical(req, timeout=timeout)

    def cache_meshes(self, req: MeshCacheRequest, *, timeout: float) -> MeshCacheResult:
        return self.render.cache_meshes(req, timeout=timeout)

    def request(self, payload: dict[str, Any], *, timeout: float) -> dict[str, Any]:
        return self.render.request(payload, timeout=timeout)

    def _shut(self) -> bool:
        """Mark closed (no settle starts after this); True when a settle was in flight."""
        with self._turn:
            self._closed = True
            pending, self._pending = self._pending, None
            self._turn.notify_all()
        return pending is not None

    def kill(self) -> None:
        """Both processes killed now (first: a settle being collected then ends at once)."""
        self.render.kill()
        self.settler.kill()
        self._shut()

    def close(self) -> None:
        """Both processes asked to exit; a companion still settling (its scene will not come) is killed."""
        if self._shut():
            self.settler.kill()
        self.render.close()
        self.settler.close()

    def __enter__(self) -> "SettleAheadWorker":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
