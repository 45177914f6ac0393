"""Executors run :class:`~mixcount.run.scene_task.SceneTask` s; this is the local one.

The interface every executor implements (a Ray one lives in ``mixcount/run/ray_executor.py``):

* ``slots`` - how many scenes may be in flight at once;
* ``submit(task)`` - queue one task;
* ``next_outcome(timeout=None)`` - block until some task finishes, return its
  :class:`~mixcount.run.scene_task.SceneOutcome` (completion order, not submission order);
* ``close()`` - stop the workers (also via ``with``).

:class:`LocalExecutor` keeps ``workers`` threads, each owning one long-lived
:class:`~mixcount.blender.worker.BlenderWorker` subprocess (bpy never runs in this process); a worker
that crashes or times out is restarted by its next task.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import Any, Callable, Optional, Protocol

from mixcount.run.scene_task import SceneOutcome, SceneTask, run_scene_task


class Executor(Protocol):
    slots: int

    def submit(self, task: SceneTask) -> None: ...

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome: ...

    def close(self) -> None: ...


class LocalExecutor:
    """A pool of ``workers`` bpy worker processes on this machine."""

    def __init__(self, workers: int, *, log_dir: Optional[Path] = None,
                 runner: Callable[[SceneTask, Any], SceneOutcome] = run_scene_task, recycle_after: int) -> None:
        from mixcount.blender.worker import BlenderWorker

        self.recycle_after = max(0, int(recycle_after))  # restart a worker after this many scenes (flat memory)

        self.slots = max(1, int(workers))
        self._tasks: "queue.Queue[Optional[SceneTask]]" = queue.Queue()
        self._outcomes: "queue.Queue[SceneOutcome]" = queue.Queue()
        self.workers = [BlenderWorker(name=f"worker{k}", log_dir=log_dir) for k in range(self.slots)]
        self._runner = runner
        self._threads = [threading.Thread(target=self._loop, args=(w,), daemon=True) for w in self.workers]
        for t in self._threads:
            t.start()

    def _loop(self, worker: Any) -> None:
        done = 0
        while True:
            task = self._tasks.get()
            if task is None:
                return
            try:
                outcome = self._runner(task, worker)
            except Exception as exc:  # noqa: BLE001 - never lose a task's outcome
                # "OSError: [Errno 28] No space left on device: '...'", as run_scene_task words it, so the
                # run can tell a fault no seed fixes (mixcount.run.faults) from a bad scene
                outcome = SceneOutcome(task.spec.scene_id, task.spec.seed, "failed", 0.0,
                                       error=f"{type(exc).__name__}: {exc}"[:4000])
            done += 1
            if self.recycle_after and done % self.recycle_after == 0:
                worker.close()  # the next task starts a fresh bpy process
            self._outcomes.put(outcome)

    def submit(self, task: SceneTask) -> None:
        self._tasks.put(task)

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome:
        return self._outcomes.get(timeout=timeout)

    def close(self) -> None:
        for _ in self._threads:
            self._tasks.put(None)
        for t in self._threads:
            t.join(timeout=2)
        for t, w in zip(self._threads, self.workers):
            if t.is_alive():  # still inside a scene (interrupted run): do not wait for it
                w.kill()
            else:
                w.close()

    def __enter__(self) -> "LocalExecutor":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
