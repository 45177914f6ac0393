"""The one worker pool (mixcount.worker.pool) that the local executor, the Ray actor and canonical renders
share: the recycle rule, the error format, no lost answer, an interrupted pool starting no queued job.
Fake workers stand in for bpy here; the real ones run through it in test_blender_worker.py (a worker
killed mid-scene), test_renders.py (a hung and a crashed render) and test_ray_executor.py."""

from __future__ import annotations

import threading
import time

import pytest

from mixcount.worker.pool import MAX_ERROR_CHARS, WorkerPool, WorkerSlot, error_text


class FakeWorker:
    made = 0

    def __init__(self) -> None:
        FakeWorker.made += 1
        self.serial = FakeWorker.made
        self.closed = self.killed = False

    def close(self) -> None:
        self.closed = True

    def kill(self) -> None:
        self.killed = True


def test_slot_recycles_after_n_jobs_counting_failed_ones() -> None:
    slot = WorkerSlot(FakeWorker, recycle_after=2)
    seen = [slot.run(lambda w: w.serial), slot.run(lambda w: w.serial)]
    first = slot.current
    assert first is None  # closed after its second job
    with pytest.raises(ValueError):
        slot.run(lambda w: (_ for _ in ()).throw(ValueError("boom")))
    seen.append(slot.run(lambda w: w.serial))
    assert seen[0] == seen[1] and seen[2] == seen[0] + 1  # a failed job counts towards the recycle
    assert (slot.total, slot.recycled, slot.current) == (4, 2, None)
    never = WorkerSlot(FakeWorker, recycle_after=0)
    assert len({never.run(lambda w: w.serial) for _ in range(5)}) == 1 and never.recycled == 0


def test_error_text_is_type_and_message_cut_at_the_limit() -> None:
    assert error_text(OSError(28, "No space left on device")) == "OSError: [Errno 28] No space left on device"
    assert len(error_text(RuntimeError("x" * 10 * MAX_ERROR_CHARS))) == MAX_ERROR_CHARS


def test_pool_answers_every_job_and_turns_exceptions_into_results() -> None:
    def handle(worker: FakeWorker, job: int) -> str:
        if job % 3 == 0:
            raise ValueError(f"job {job} planted")
        return f"ok {job}"

    pool: WorkerPool[int, str] = WorkerPool(2, lambda k: FakeWorker(), recycle_after=2, handle=handle,
                                            on_error=lambda job, exc: f"failed {job}: {error_text(exc)}")
    for j in range(9):
        pool.submit(j)
    got = sorted(pool.next_result(timeout=10) for _ in range(9))
    pool.close()
    assert got == sorted([f"ok {j}" for j in range(9) if j % 3] +
                         [f"failed {j}: ValueError: job {j} planted" for j in range(0, 9, 3)])
    assert sum(s.total for s in pool.slots) == 9 and sum(s.recycled for s in pool.slots) >= 3
    assert not pool.alive()


def test_killed_pool_starts_no_queued_job() -> None:
    started: list[int] = []
    release = threading.Event()

    def handle(worker: FakeWorker, job: int) -> int:
        started.append(job)
        release.wait(5)
        return job

    pool: WorkerPool[int, int] = WorkerPool(1, lambda k: FakeWorker(), recycle_after=0, handle=handle,
                                            on_error=lambda job, exc: -job)
    for j in range(5):
        pool.submit(j)
    while not started:
        time.sleep(0.01)
    worker = pool.slots[0].current
    threading.Timer(0.3, release.set).start()  # job 0 ends only after close has dropped the queue
    pool.close(kill=True, join_s=5.0)
    assert started == [0] and worker.killed and not pool.alive()
