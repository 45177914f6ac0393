"""Where the per-object work of the catalog steps runs: here (the default) or on a Ray cluster.

The steps (`catalog ingest`'s mesh analysis, `render`, `filter`'s descriptors and pair figures, `caption`)
ask :func:`ray_tasks`; None means their local pools, anything else is a cluster connection (a
:class:`mixcount.run.catalog_tasks.RayTasks`, set for the command by
:func:`mixcount.run.catalog_tasks.catalog_executor`) with ``map(fn, args)``: ``fn(*a)`` for each ``a``,
results in the order of ``args``, a :class:`TaskFailed` for a task that died on every try, ``cpus()`` and
``put(value)``. Kept in this low room, apart from the connection itself, so the steps depend on this
contract only and on no Ray code.
"""

from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass
from typing import Any, Iterator, Optional, Sequence

from mixcount.task_memory import collected_when_grown, forked_worker_start

_current: contextvars.ContextVar[Optional[Any]] = contextvars.ContextVar("catalog_step_cluster", default=None)


@dataclass(frozen=True)
class TaskFailed:
    """What a cluster's ``map`` yields for work whose task could not finish (after its retries): the reason."""

    error: str


def run_and_collect(fn: Any, *args: Any) -> Any:
    """``fn(*args)`` in a worker that lives for many tasks, then a full garbage collection when the worker
    has grown enough (:func:`mixcount.task_memory.collected_when_grown`): what one object's task left in
    reference cycles (trimesh meshes) is freed before it piles up. Every executor of the catalog steps
    runs its tasks through this (local processes, this process, Ray tasks, ingest's analysis pool)."""
    with collected_when_grown():
        return fn(*args)


def ray_tasks() -> Optional[Any]:
    """The Ray cluster the current catalog command runs its per-object work on, or None (local)."""
    return _current.get()


def use_cluster(cluster: Optional[Any]) -> contextvars.Token[Optional[Any]]:
    """Make ``cluster`` the steps' :func:`ray_tasks` (undo with :func:`release`)."""
    return _current.set(cluster)


def release(token: contextvars.Token[Optional[Any]]) -> None:
    _current.reset(token)


def chunks(items: Sequence[Any], size: int) -> list[list[Any]]:
    """``items`` cut into lists of at most ``size`` (at least 1), in order."""
    size = max(1, int(size))
    return [list(items[i:i + size]) for i in range(0, len(items), size)]


class LocalProcesses:
    """The same ``map`` / ``cpus`` / ``put`` contract as a Ray cluster, on ``workers`` forked processes of
    this machine: what lets a step that was written for the cluster (``catalog filter``'s descriptors and
    pair figures, issue 69) use every core here too, with the same results in the same order.

    A worker that dies (segfault, OOM kill) breaks the pool; each item still pending is then run again alone
    in a fresh process, and one that kills that too comes back as :class:`TaskFailed` with its reason, as a
    cluster's task does after its retries. Use as a context manager (the pool is shut down on leaving)."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self._pool: Any = None

    def __enter__(self) -> "LocalProcesses":
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if self._pool is None:
            return
        if exc_type is not None:  # stopped (Ctrl-C, SIGTERM) or failed: end the tasks in flight, do not wait
            for proc in list((getattr(self._pool, "_processes", None) or {}).values()):
                with contextlib.suppress(OSError, AttributeError):
                    proc.terminate()
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None

    def cpus(self) -> int:
        return self.workers

    def put(self, value: Any) -> Any:
        return value  # a forked worker gets it with each task's arguments

    def map(self, fn: Any, args: Sequence[Sequence[Any]]) -> Iterator[Any]:
        """``fn(*a)`` for each ``a`` on the workers, yielded in the order of ``args`` as each is done (so a
        caller can show progress); a task that raised yields a :class:`TaskFailed` with its type and first
        line, as a Ray task that failed does."""
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool

        if not args:
            return
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=min(self.workers, len(args)), initializer=forked_worker_start)
        futures = [self._pool.submit(run_and_collect, fn, *a) for a in args]
        failed = False
        try:
            for fut, a in zip(futures, args):
                try:
                    got = fut.result()
                except BrokenProcessPool:
                    got = _alone(fn, a)
                except Exception as exc:  # noqa: BLE001 - any error of the task's own code
                    got = TaskFailed(error_line(exc))
                failed = failed or isinstance(got, TaskFailed)
                yield got
        finally:
            if failed or getattr(self._pool, "_broken", False):
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None  # a fresh pool for the next map


class InThisProcess:
    """The cluster contract run in this process, one task after the other: what ``[filter] workers = 1``
    uses, so the filter takes one path (figures computed by chunk, the rules on the filled cache, progress
    per chunk) whichever executor runs its tasks."""

    def __enter__(self) -> "InThisProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def cpus(self) -> int:
        return 1

    def put(self, value: Any) -> Any:
        return value

    def map(self, fn: Any, args: Sequence[Sequence[Any]]) -> Iterator[Any]:
        for a in args:
            try:
                yield run_and_collect(fn, *a)
            except Exception as exc:  # noqa: BLE001 - as a worker's task error
                yield TaskFailed(error_line(exc))


def error_line(exc: BaseException, limit: int = 500) -> str:
    """One line for a task's error: its type and the first line of its message (every executor's failures)."""
    first = (str(exc).strip().splitlines() or [""])[0]
    return f"{type(exc).__name__}: {first}"[:limit]


def _alone(fn: Any, a: Sequence[Any]) -> Any:
    """``fn(*a)`` in a fresh process of its own: the item that killed a pool is told from the others."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    with ProcessPoolExecutor(max_workers=1, initializer=forked_worker_start) as solo:
        try:
            return solo.submit(fn, *a).result()
        except BrokenProcessPool as exc:
            return TaskFailed(f"its worker process died: {exc}")
        except Exception as exc:  # noqa: BLE001 - the task's own error, as in LocalProcesses.map
            return TaskFailed(error_line(exc))
