"""Executors run :class:`~mixcount.run.scene_task.SceneTask` s; this is the local one.

The interface every executor implements (a Ray one lives in ``mixcount/run/ray_executor.py``):

* ``slots`` - how many scenes may be in flight at once;
* ``submit(task)`` - queue one task;
* ``next_outcome(timeout=None)`` - block until some task finishes, return its
  :class:`~mixcount.run.scene_task.SceneOutcome` (completion order, not submission order);
* ``close()`` - stop the workers (also via ``with``).

:class:`LocalExecutor` is a :class:`~mixcount.worker.pool.WorkerPool` of ``workers`` slots, each owning
one long-lived :class:`~mixcount.worker.client.BlenderWorker` subprocess (bpy never runs in this process),
recycled after ``compose.recycle_after`` scenes; a worker that crashes or times out is restarted by its
next task. With ``settle_ahead`` (``compose.settle_ahead``) each slot is a
:class:`~mixcount.worker.settle_ahead.SettleAheadWorker`: while a scene renders, the slot's next scene is
staged and settled in a companion bpy process (the pool's prefetch), and the executor takes two scenes
per worker (``slots``) so that there is always a next one.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any, Optional, Protocol

from mixcount.run.scene_task import FAILED, SceneOutcome, SceneRunner, SceneTask, run_scene_task
from mixcount.worker.client import Worker


class Executor(Protocol):
    slots: int

    def submit(self, task: SceneTask) -> None: ...

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome: ...

    def close(self) -> None: ...


class LocalExecutor:
    """A pool of ``workers`` bpy worker processes on this machine (:class:`~mixcount.worker.pool.WorkerPool`)."""

    def __init__(self, workers: int, *, log_dir: Optional[Path] = None, runner: SceneRunner = run_scene_task,
                 recycle_after: int, settle_ahead: bool, cpu_threads: int = 0) -> None:
        """``cpu_threads`` > 0: every scene renders with that many Cycles threads (it replaces each task's), and
        each worker's bpy is started for that many (:class:`~mixcount.worker.client.BlenderWorker`)."""
        from mixcount.run.staging_ahead import StagingAhead
        from mixcount.worker.client import BlenderWorker
        from mixcount.worker.pool import WorkerPool, error_text
        from mixcount.worker.settle_ahead import SettleAheadWorker

        n_workers = max(1, int(workers))
        self.cpu_threads = max(0, int(cpu_threads))
        self.slots = 2 * n_workers if settle_ahead else n_workers
        self._ahead = StagingAhead() if settle_ahead else None

        def failed(task: SceneTask, exc: BaseException) -> SceneOutcome:
            # "OSError: [Errno 28] No space left on device: '...'", as run_scene_task words it, so the
            # run can tell a fault no seed fixes (mixcount.run.faults) from a bad scene
            return SceneOutcome(task.spec.scene_id, task.spec.seed, FAILED, 0.0, error=error_text(exc))

        def handle(worker: Worker, task: SceneTask) -> SceneOutcome:
            staged = self._ahead.claim(task) if self._ahead is not None else None
            if staged is None:
                return runner(task, worker)
            try:  # the runner is never bypassed: it gets the stage written ahead
                return runner(task, worker, staged)
            finally:
                if not task.keep_failed:  # gone already unless the runner left it behind
                    shutil.rmtree(staged.tmp, ignore_errors=True)

        def make(k: int) -> Worker:
            cls = SettleAheadWorker if settle_ahead else BlenderWorker
            return cls(name=f"worker{k}", log_dir=log_dir, cpu_threads=self.cpu_threads)

        # recycle_after: restart a worker after this many scenes (flat memory), the pool's one rule
        self._pool: WorkerPool[SceneTask, SceneOutcome] = WorkerPool(
            n_workers, make, recycle_after=recycle_after, handle=handle, on_error=failed,
            prefetch=self._ahead.prefetch if self._ahead is not None else None)

    @property
    def workers(self) -> list[Worker]:
        """The current BlenderWorker of each slot."""
        return self._pool.workers

    def submit(self, task: SceneTask) -> None:
        if self.cpu_threads:  # the threads its workers were started for
            task = dataclasses.replace(task, threads=self.cpu_threads)
        self._pool.submit(task)

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome:
        return self._pool.next_result(timeout=timeout)

    def close(self) -> None:
        """Stop the workers; one still inside a scene (an interrupted run) is killed, not waited for. The
        stage folders of scenes staged ahead that never ran are removed."""
        self._pool.close()
        if self._ahead is not None:
            self._ahead.discard_all()

    def __enter__(self) -> "LocalExecutor":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
