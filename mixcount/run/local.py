"""Executors run :class:`~mixcount.run.scene_task.SceneTask` s; this is the local one.

The interface every executor implements (a Ray one lives in ``mixcount/run/ray_executor.py``):

* ``slots`` - how many scenes may be in flight at once;
* ``submit(task)`` - queue one task;
* ``next_outcome(timeout=None)`` - block until some task finishes, return its
  :class:`~mixcount.run.scene_task.SceneOutcome` (completion order, not submission order);
* ``close()`` - stop the workers (also via ``with``).

:class:`LocalExecutor` is a :class:`~mixcount.blender.pool.WorkerPool` of ``workers`` slots, each owning
one long-lived :class:`~mixcount.blender.worker.BlenderWorker` subprocess (bpy never runs in this process),
recycled after ``compose.recycle_after`` scenes; a worker that crashes or times out is restarted by its
next task.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Optional, Protocol

from mixcount.run.scene_task import FAILED, SceneOutcome, SceneTask, run_scene_task


class Executor(Protocol):
    slots: int

    def submit(self, task: SceneTask) -> None: ...

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome: ...

    def close(self) -> None: ...


class LocalExecutor:
    """A pool of ``workers`` bpy worker processes on this machine (:class:`~mixcount.blender.pool.WorkerPool`)."""

    def __init__(self, workers: int, *, log_dir: Optional[Path] = None,
                 runner: Callable[[SceneTask, Any], SceneOutcome] = run_scene_task, recycle_after: int) -> None:
        from mixcount.blender.pool import WorkerPool, error_text
        from mixcount.blender.worker import BlenderWorker

        self.slots = max(1, int(workers))

        def failed(task: SceneTask, exc: BaseException) -> SceneOutcome:
            # "OSError: [Errno 28] No space left on device: '...'", as run_scene_task words it, so the
            # run can tell a fault no seed fixes (mixcount.run.faults) from a bad scene
            return SceneOutcome(task.spec.scene_id, task.spec.seed, FAILED, 0.0, error=error_text(exc))

        # recycle_after: restart a worker after this many scenes (flat memory), the pool's one rule
        self._pool: WorkerPool[SceneTask, SceneOutcome] = WorkerPool(
            self.slots, lambda k: BlenderWorker(name=f"worker{k}", log_dir=log_dir), recycle_after=recycle_after,
            handle=lambda worker, task: runner(task, worker), on_error=failed)

    @property
    def workers(self) -> list[Any]:
        """The current BlenderWorker of each slot."""
        return self._pool.workers

    def submit(self, task: SceneTask) -> None:
        self._pool.submit(task)

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome:
        return self._pool.next_result(timeout=timeout)

    def close(self) -> None:
        """Stop the workers; one still inside a scene (an interrupted run) is killed, not waited for."""
        self._pool.close()

    def __enter__(self) -> "LocalExecutor":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
