"""A long-lived worker frees what its last tasks left in reference cycles once it has grown enough.

A worker process (a catalog step's pool process or Ray worker, a bpy worker) lives for many objects. What
one object's task builds in reference cycles (trimesh meshes and their caches, the glTF importer's objects)
waits for Python's next full collection, and full collections count container objects, not bytes: a
filter worker reached 2,175 MB resident after 5 captures of 1.2 M faces, a canonical-render worker grew
~45 MB with each (docs/performance.md). A full collection after every task fixed that but is not free: a
forked ingest worker holds its parent's ~157,000 objects, and each collection took 0.1-0.13 s against
0.01-0.03 s for a light object's analysis. :func:`collected_when_grown` therefore collects after a task only
when the process has grown by :data:`GROWTH_MB` since the last collection (or its first task began): a
capture's task always, a run of light objects every so often, and the worker's memory stays within one
object's peak plus that margin.
"""

from __future__ import annotations

import gc
import os
from contextlib import contextmanager
from typing import Iterator, Optional

GROWTH_MB = 200  # resident growth since the last collection that makes the next task end with one
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_floor: Optional[int] = None  # resident bytes after this process's last collection (or before its first task)


def _forget_floor() -> None:
    global _floor
    _floor = None  # a forked child measures its own growth, not its parent's


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_floor)


def forked_worker_start() -> None:
    """``initializer`` of a forked pool process: what it inherited from its parent is frozen
    (``gc.freeze``), so its collections examine only its own objects. A collection in a child of a process
    with threads must not finalize the parent's garbage: a finalizer may take a lock that another thread of
    the parent held at the fork, and the child would wait for it for ever; freezing also spares the
    copy-on-write of every inherited object a collection would touch."""
    gc.freeze()


def resident_bytes() -> Optional[int]:
    """This process's resident size from /proc (Linux); None where it cannot be read."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


@contextmanager
def collected_when_grown(growth_mb: float = GROWTH_MB) -> Iterator[None]:
    """Run one task; after it, a full collection when the process has grown by ``growth_mb`` since the last
    one, or since it was smallest after it (always where the resident size cannot be read). Without the
    second part a process that had returned memory (a freed 300 MB buffer) grew back unseen: its floor stayed
    where the last collection left it, above what it now held (the suite's long-lived process; test below)."""
    global _floor
    start = resident_bytes()
    if _floor is None or (start is not None and start < _floor):
        _floor = start  # a process that returned memory since (freed mmaps) grows from where it is now
    try:
        yield
    finally:
        now = resident_bytes()
        if now is None or _floor is None or now - _floor > growth_mb * 2**20:
            gc.collect()
            _floor = resident_bytes()
