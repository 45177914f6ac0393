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

import contextvars
from dataclasses import dataclass
from typing import Any, Optional, Sequence

_current: contextvars.ContextVar[Optional[Any]] = contextvars.ContextVar("catalog_step_cluster", default=None)


@dataclass(frozen=True)
class TaskFailed:
    """What a cluster's ``map`` yields for work whose task could not finish (after its retries): the reason."""

    error: str


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

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def cpus(self) -> int:
        return self.workers

    def put(self, value: Any) -> Any:
        return value  # a forked worker gets it with each task's arguments

    def map(self, fn: Any, args: Sequence[Sequence[Any]]) -> list[Any]:
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool

        if not args:
            return []
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=min(self.workers, len(args)))
        futures = [self._pool.submit(fn, *a) for a in args]
        out: list[Any] = []
        for fut, a in zip(futures, args):
            try:
                out.append(fut.result())
            except BrokenProcessPool:
                out.append(_alone(fn, a))
        if any(isinstance(o, TaskFailed) for o in out) or getattr(self._pool, "_broken", False):
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None  # a fresh pool for the next map
        return out


def _alone(fn: Any, a: Sequence[Any]) -> Any:
    """``fn(*a)`` in a fresh process of its own: the item that killed a pool is told from the others."""
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    with ProcessPoolExecutor(max_workers=1) as solo:
        try:
            return solo.submit(fn, *a).result()
        except BrokenProcessPool as exc:
            return TaskFailed(f"its worker process died: {exc}")
