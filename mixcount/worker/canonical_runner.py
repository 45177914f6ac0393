"""Parent side of the canonical renders (no bpy here): jobs over long-lived bpy workers.

:func:`run_jobs` shares the jobs among ``workers`` :class:`~mixcount.worker.client.BlenderWorker` s of one
:class:`~mixcount.worker.pool.WorkerPool` (the pool compose uses; op ``canonical``). A job that runs longer than ``timeout_s``
gets its worker killed and is reported failed ("timed out"); a worker that dies mid-job (segfault, out of
memory) is reported the same way with its log tail; in both cases the next job starts a fresh worker and
the batch goes on. Results reach the caller through ``on_result(outcome)`` (a :class:`RenderOutcome`) on
the calling thread, so the caller may write to its database there.
"""

from __future__ import annotations

import os
import queue
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from mixcount.worker.canonical_contract import CanonicalRequest, CanonicalResult
from mixcount.worker.pool import WorkerPool, error_text

Job = tuple[str, CanonicalRequest]  # (the caller's key, the request)


@dataclass(frozen=True)
class RenderOutcome:
    """One job's end: its ``result``, or the ``error`` (one line and the worker's log tail) that stopped it."""

    key: str
    result: Optional[CanonicalResult]
    error: Optional[str] = None


def run_jobs(jobs: Sequence[Job], *, on_result: Callable[[RenderOutcome], None],
             workers: int, timeout_s: float, threads_per_worker: int) -> None:
    """Render ``jobs`` ((unique key, request) pairs) in ``workers`` processes (a
    :class:`~mixcount.worker.pool.WorkerPool`); call ``on_result`` once per job with its outcome, on this
    thread, as results arrive. ``threads_per_worker`` 0 means all cores for one worker, cores / workers
    for several (it replaces each request's ``threads``)."""
    from mixcount.worker.client import BlenderWorker

    if not jobs:
        return
    workers = max(1, min(int(workers), len(jobs)))
    if threads_per_worker <= 0 and workers > 1:
        threads_per_worker = max(1, (os.cpu_count() or 1) // workers)

    def render(worker: Any, job: Job) -> RenderOutcome:
        return RenderOutcome(job[0], worker.render_canonical(job[1], timeout=timeout_s))

    def failed(job: Job, exc: BaseException) -> RenderOutcome:
        return RenderOutcome(job[0], None, error_text(exc))

    with tempfile.TemporaryDirectory(prefix="mixcount-canonical-") as tmp:
        pool: WorkerPool[Job, RenderOutcome] = WorkerPool(
            workers, lambda k: BlenderWorker(name=f"render{k}", log_dir=Path(tmp),
                                    cpu_threads=threads_per_worker),
            recycle_after=0,
            handle=render, on_error=failed)
        for key, req in jobs:
            pool.submit((key, replace(req, threads=int(threads_per_worker))))
        seen = 0
        try:
            while seen < len(jobs):
                try:
                    outcome = pool.next_result(timeout=0.5)
                except queue.Empty:
                    if not pool.alive():
                        break
                    continue
                seen += 1
                on_result(outcome)
        finally:
            # interrupted: do not wait for the renders in progress
            pool.close(kill=seen < len(jobs), join_s=30.0)


RAY_CHUNK = 8  # canonical renders per Ray task: one bpy start (~2 s) shared by this many objects


def render_chunk(jobs: Sequence[Job], timeout_s: float, threads: int) -> list[RenderOutcome]:
    """Ray task of ``catalog render --executor ray``: ``jobs`` rendered in order by one bpy worker of this
    node (:func:`run_jobs` with one worker, ``threads`` Cycles threads, 0: 1), one outcome each."""
    got: list[RenderOutcome] = []
    run_jobs(jobs, on_result=got.append, workers=1, timeout_s=timeout_s, threads_per_worker=max(1, int(threads)))
    done = {o.key for o in got}
    got += [RenderOutcome(key, None, "render worker stopped before this object") for key, _ in jobs if key not in done]
    return got


def run_jobs_on_ray(cluster: Any, jobs: Sequence[Job], *, on_result: Callable[[RenderOutcome], None],
                    timeout_s: float, threads_per_worker: int) -> None:
    """:func:`run_jobs` on a Ray cluster (:class:`mixcount.run.catalog_tasks.RayTasks`): chunks of at most
    :data:`RAY_CHUNK` jobs (fewer where a CPU of the cluster would get less than two chunks) as tasks,
    ``on_result`` called here, in the order of ``jobs``; a chunk whose
    task died on every try fails its objects with the reason."""
    from mixcount.catalog.step_executor import TaskFailed, chunks

    per = max(1, min(RAY_CHUNK, -(-len(jobs) // (2 * cluster.cpus()))))  # two chunks a CPU at least
    parts = chunks(list(jobs), per)
    for part, got in zip(parts, cluster.map(render_chunk, [(p, timeout_s, threads_per_worker) for p in parts])):
        if isinstance(got, TaskFailed):
            got = [RenderOutcome(key, None, got.error) for key, _ in part]
        for outcome in got:
            on_result(outcome)
