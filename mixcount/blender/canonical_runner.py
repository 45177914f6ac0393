"""Parent side of the canonical renders (no bpy here): jobs over long-lived bpy workers.

:func:`run_jobs` shares the jobs among ``workers`` :class:`~mixcount.blender.worker.BlenderWorker` s, the
same JSON-lines worker that renders scenes (op ``canonical``). A job that runs longer than ``timeout_s``
gets its worker killed and is reported failed ("timed out"); a worker that dies mid-job (segfault, out of
memory) is reported the same way with its log tail; in both cases the next job starts a fresh worker and
the batch goes on. Results reach the caller through ``on_result(outcome)`` (a :class:`RenderOutcome`) on
the calling thread, so the caller may write to its database there.
"""

from __future__ import annotations

import os
import queue
import tempfile
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from mixcount.blender.contract import CanonicalRequest, CanonicalResult
from mixcount.errors import RenderError

MAX_ERROR_CHARS = 2000
Job = tuple[str, CanonicalRequest]  # (the caller's key, the request)


@dataclass(frozen=True)
class RenderOutcome:
    """One job's end: its ``result``, or the ``error`` (one line and the worker's log tail) that stopped it."""

    key: str
    result: Optional[CanonicalResult]
    error: Optional[str] = None


def _serve(worker: Any, jobs: "queue.Queue[Optional[Job]]", timeout_s: float,
           out: "queue.Queue[RenderOutcome]", stop: threading.Event) -> None:
    try:
        while not stop.is_set():
            job = jobs.get()
            if job is None:
                return
            key, req = job
            try:
                outcome = RenderOutcome(key, worker.render_canonical(req, timeout=timeout_s))
            except RenderError as exc:
                outcome = RenderOutcome(key, None, str(exc).strip()[:MAX_ERROR_CHARS])
            out.put(outcome)
    finally:
        worker.close()


def run_jobs(jobs: Sequence[Job], *, on_result: Callable[[RenderOutcome], None],
             workers: int, timeout_s: float, threads_per_worker: int) -> None:
    """Render ``jobs`` ((unique key, request) pairs) in ``workers`` processes; call ``on_result`` once per
    job with its outcome, on this thread, as results arrive. ``threads_per_worker`` 0 means all cores for
    one worker, cores / workers for several (it replaces each request's ``threads``)."""
    from mixcount.blender.worker import BlenderWorker

    if not jobs:
        return
    workers = max(1, min(int(workers), len(jobs)))
    if threads_per_worker <= 0 and workers > 1:
        threads_per_worker = max(1, (os.cpu_count() or 1) // workers)
    todo: "queue.Queue[Optional[Job]]" = queue.Queue()
    for key, req in jobs:
        todo.put((key, replace(req, threads=int(threads_per_worker))))
    for _ in range(workers):
        todo.put(None)
    results: "queue.Queue[RenderOutcome]" = queue.Queue()
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="mixcount-canonical-") as tmp:
        pool = [BlenderWorker(name=f"render{w}", log_dir=Path(tmp)) for w in range(workers)]
        threads = [threading.Thread(target=_serve, args=(w, todo, timeout_s, results, stop), daemon=True)
                   for w in pool]
        for t in threads:
            t.start()
        seen = 0
        try:
            while seen < len(jobs):
                try:
                    outcome = results.get(timeout=0.5)
                except queue.Empty:
                    if not any(t.is_alive() for t in threads) and results.empty():
                        break
                    continue
                seen += 1
                on_result(outcome)
        finally:
            stop.set()
            if seen < len(jobs):  # interrupted: do not wait for the renders in progress
                for w in pool:
                    w.kill()
            for t in threads:
                t.join(timeout=30)
