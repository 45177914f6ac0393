"""One pool of bpy workers for every caller: the local scene executor, the Ray scene actor and the
canonical renders share :class:`WorkerSlot` (one recycle rule) and :func:`error_text` (one error format).

* :class:`WorkerSlot` - one long-lived worker (a :class:`~mixcount.worker.client.BlenderWorker`, made
  by a factory on first use). After ``recycle_after`` jobs (0 = never) it is closed and the next job gets
  a fresh one from the factory, so a bpy process's memory stays flat over a long run. A job that raises
  still counts.
* :class:`WorkerPool` - ``size`` slots, each served by a thread that takes jobs from one queue and puts
  results on another (completion order). A job that raises becomes ``on_error(job, exc)``: the pool never
  loses a job's answer and its threads never die of one. With ``prefetch``, while a thread handles a job a
  second thread takes the NEXT queued job as soon as it is submitted and calls ``prefetch(worker,
  next_job)`` on the current job's worker (the settle-ahead worker settles it in a second process while
  the current job renders); that job is the slot's next.
* :func:`error_text` - ``"<ExceptionType>: <message>"``, at most :data:`MAX_ERROR_CHARS` characters: what a
  failed scene or render records (mixcount.run.faults reads a full disk's errno from it).
"""

from __future__ import annotations

import functools
import queue
import threading
from typing import Any, Callable, Generic, Optional, TypeVar

MAX_ERROR_CHARS = 4000

J = TypeVar("J")
R = TypeVar("R")
T = TypeVar("T")


def error_text(exc: BaseException) -> str:
    """The one error format of a failed job: exception type and message, cut at MAX_ERROR_CHARS."""
    return f"{type(exc).__name__}: {exc}"[:MAX_ERROR_CHARS]


class WorkerSlot:
    """One worker, made by ``factory`` on first use and replaced after ``recycle_after`` jobs."""

    def __init__(self, factory: Callable[[], Any], *, recycle_after: int) -> None:
        self.factory = factory
        self.recycle_after = max(0, int(recycle_after))
        self.current: Any = None  # the worker now in use (None before the first job and after a recycle)
        self.jobs = 0  # jobs run by the current worker
        self.total = 0
        self.recycled = 0

    @property
    def worker(self) -> Any:
        if self.current is None:
            self.current = self.factory()
            self.jobs = 0
        return self.current

    def run(self, job: Callable[[Any], T]) -> T:
        """``job(worker)``; afterwards (also when it raised) the worker is recycled when its turn has come."""
        try:
            return job(self.worker)
        finally:
            self.jobs += 1
            self.total += 1
            if self.recycle_after and self.jobs >= self.recycle_after:
                self.close()
                self.recycled += 1

    def close(self) -> None:
        """Ask the worker to exit (the next job starts a fresh one)."""
        worker, self.current = self.current, None
        if worker is not None:
            worker.close()

    def kill(self) -> None:
        """Kill the worker at once (it may be inside a job: an interrupted run)."""
        worker, self.current = self.current, None
        if worker is not None and hasattr(worker, "kill"):
            worker.kill()


class WorkerPool(Generic[J, R]):
    """``size`` worker slots serving one job queue (see the module docstring)."""

    def __init__(self, size: int, factory: Callable[[int], Any], *, recycle_after: int,
                 handle: Callable[[Any, J], R], on_error: Callable[[J, BaseException], R],
                 prefetch: Optional[Callable[[Any, J], None]] = None) -> None:
        self.size = max(1, int(size))
        self._prefetch = prefetch
        self._stopping = False  # close() was called: a prefetched job no longer starts
        self.slots = [WorkerSlot(functools.partial(factory, k), recycle_after=recycle_after) for k in range(self.size)]
        self._handle, self._on_error = handle, on_error
        self._jobs: "queue.Queue[Optional[J]]" = queue.Queue()
        self._results: "queue.Queue[R]" = queue.Queue()
        self._threads = [threading.Thread(target=self._serve, args=(s,), daemon=True) for s in self.slots]
        for t in self._threads:
            t.start()

    @property
    def workers(self) -> list[Any]:
        """Each slot's worker (made now when a slot has none yet)."""
        return [s.worker for s in self.slots]

    def _look_ahead(self, worker: Any, done: threading.Event, box: list[Optional[J]]) -> None:
        """Runs beside the current job: take the next queued job as soon as the caller submits it (or the
        stop signal) into ``box`` and prefetch it on ``worker``, the current job's; gives up once ``done``."""
        while not done.is_set():
            try:
                job = self._jobs.get(timeout=0.05)
            except queue.Empty:
                continue
            box.append(job)
            if job is not None and not self._stopping:
                try:
                    assert self._prefetch is not None
                    self._prefetch(worker, job)
                except Exception:  # noqa: BLE001 - a failed prefetch only means the job runs without it
                    pass
            return

    def _serve(self, slot: WorkerSlot) -> None:
        job: Optional[J] = None
        while True:
            if job is None:
                job = self._jobs.get()
                if job is None:
                    return
            box: list[Optional[J]] = []
            done, looker = threading.Event(), None
            if self._prefetch is not None:
                looker = threading.Thread(target=self._look_ahead, args=(slot.worker, done, box), daemon=True)
                looker.start()
            try:
                result = slot.run(lambda worker, job=job: self._handle(worker, job))  # type: ignore[misc]
            except Exception as exc:  # noqa: BLE001 - never lose a job's answer
                result = self._on_error(job, exc)
            done.set()
            if looker is not None:
                looker.join()
            self._results.put(result)
            if box and (self._stopping or box[0] is None):  # the job taken ahead does not start
                return
            job = box[0] if box else None

    def submit(self, job: J) -> None:
        self._jobs.put(job)

    def next_result(self, timeout: Optional[float] = None) -> R:
        """The next finished job's result (completion order); ``queue.Empty`` after ``timeout`` seconds."""
        return self._results.get(timeout=timeout)

    def alive(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def close(self, *, kill: bool = False, join_s: float = 2.0) -> None:
        """Stop the threads and the workers: a slot still inside a job after ``join_s`` (or every slot, with
        ``kill``, queued jobs dropped) has its worker killed, the others are asked to exit. A job taken
        ahead by a look-ahead thread is dropped (the caller that closes no longer waits for it)."""
        self._stopping = True  # a job a look-ahead thread took never starts after this
        if kill:  # an interrupted run: no queued job starts, the ones in progress end now
            try:
                while True:
                    self._jobs.get_nowait()
            except queue.Empty:
                pass
            for slot in self.slots:
                slot.kill()
        for _ in self._threads:
            self._jobs.put(None)
        for t in self._threads:
            t.join(timeout=join_s)
        for t, slot in zip(self._threads, self.slots):
            if t.is_alive():
                slot.kill()
            else:
                slot.close()
