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
