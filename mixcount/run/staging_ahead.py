"""Settle-ahead, the run side: the next scene's stage written ahead and handed to the worker to settle.

:class:`StagingAhead` is what :class:`~mixcount.run.local.LocalExecutor` plugs into its
:class:`~mixcount.worker.pool.WorkerPool` when ``compose.settle_ahead`` is on: the pool's look-ahead
thread calls :meth:`StagingAhead.prefetch` with the slot's next task (its stage is written now and the
:class:`~mixcount.worker.settle_ahead.SettleAheadWorker` starts settling it in its companion process), the
slot thread then :meth:`StagingAhead.claim` s the staged scene to run it, and
:meth:`StagingAhead.discard_all` removes the stage folders of scenes staged but never run. The staged
scenes sit behind one lock: the pool's threads and the thread that closes the executor both touch them.
"""

from __future__ import annotations

import shutil
import threading
from typing import Optional

from mixcount.run.scene_task import SceneTask, StagedScene, stage_scene
from mixcount.worker.settle_ahead import SettleAheadWorker


class StagingAhead:
    """Stages written ahead, by (scene id, seed), each until its slot claims it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._staged: dict[tuple[str, int], StagedScene] = {}

    @staticmethod
    def _key(task: SceneTask) -> tuple[str, int]:
        return task.spec.scene_id, task.spec.seed

    def prefetch(self, worker: SettleAheadWorker, task: SceneTask) -> None:
        """Write ``task``'s stage now and start settling it on ``worker`` (the one that will render it);
        nothing when the scene is complete or its stage cannot be written (the run then does it all)."""
        staged = stage_scene(task)
        if staged is None:
            return
        with self._lock:
            self._staged[self._key(task)] = staged
        worker.begin_settle(staged.request)

    def claim(self, task: SceneTask) -> Optional[StagedScene]:
        """The stage written ahead for ``task`` (now the caller's to run and remove), or None."""
        with self._lock:
            return self._staged.pop(self._key(task), None)

    def discard_all(self) -> None:
        """Remove the stage folders of scenes staged ahead that never ran."""
        with self._lock:
            staged, self._staged = list(self._staged.values()), {}
        for one in staged:
            shutil.rmtree(one.tmp, ignore_errors=True)
