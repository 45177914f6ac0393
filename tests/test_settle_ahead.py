"""Settling the next scene in a companion bpy process while the current one renders (compose.settle_ahead).

The real path: the same seeds composed with and without the companion give the same scenes (poses,
annotations, id maps), and the companion really settled every scene after the first. A companion that
dies mid-settle costs nothing but time: the render worker settles that scene itself. The pool's
look-ahead (which job is prefetched on which worker, and what a kill drops) is checked with plain
Python workers beside the real run.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tests.test_blender_worker import _config, _scenes, library  # noqa: F401  (the module's fixture)

pytestmark = pytest.mark.blender


def _compose(pool, assets: Path, out: Path, *, settle_ahead: bool, n: int = 3):
    from mixcount.run.compose import compose_scenes
    from mixcount.run.local import LocalExecutor

    with LocalExecutor(1, log_dir=out.parent, recycle_after=0, settle_ahead=settle_ahead) as ex:
        summary = compose_scenes(pool=pool, config=_config(), out_dir=out, assets_dir=assets, n=n,
                                 executor=ex, progress=False)
        worker = ex._pool.slots[0].current
        ahead = worker.settled_ahead if settle_ahead else 0
        failures = list(worker.settle_failures) if settle_ahead else []
    return summary, ahead, failures


def _diag(scene: Path, kind: str) -> list[dict]:
    return [d for d in json.loads((scene / "metadata.json").read_text())["diagnostics"]
            if d.get("kind") == kind]


def test_settled_ahead_scenes_equal_scenes_settled_in_the_render_worker(library, tmp_path: Path) -> None:  # noqa: F811
    pool, assets = library
    plain, _, _ = _compose(pool, assets, tmp_path / "plain", settle_ahead=False)
    ahead, n_ahead, failures = _compose(pool, assets, tmp_path / "ahead", settle_ahead=True)
    assert plain.written == ahead.written == 3 and not failures
    assert n_ahead == 2  # every scene after the first was settled by the companion
    a_dirs, p_dirs = _scenes(tmp_path / "ahead"), _scenes(tmp_path / "plain")
    assert [d.name for d in a_dirs] == [d.name for d in p_dirs]
    marked = 0
    for a, p in zip(a_dirs, p_dirs):
        marked += bool(_diag(a, "settled_ahead"))
        assert not _diag(p, "settled_ahead")
        assert _diag(a, "rest")[0]["frames_run"] == _diag(p, "rest")[0]["frames_run"]
        ma, mp = (json.loads((d / "metadata.json").read_text()) for d in (a, p))
        assert len(ma["objects"]) == len(mp["objects"])
        for oa, op in zip(ma["objects"], mp["objects"]):
            assert (oa["name"], oa["status"], oa.get("reason")) == (op["name"], op["status"], op.get("reason"))
            if oa.get("matrix_world") is not None:
                assert np.array_equal(np.array(oa["matrix_world"]), np.array(op["matrix_world"])), oa["name"]
        ca, cp = (json.loads((d / "coco.json").read_text()) for d in (a, p))
        assert ca["annotations"] == cp["annotations"]
        assert (a / "instance.png").read_bytes() == (p / "instance.png").read_bytes()
        assert not (a / "settled.json").exists()  # the companion's file is not part of the scene
    assert marked == 2


def test_a_companion_that_dies_mid_settle_leaves_the_scene_to_the_render_worker(library, tmp_path: Path) -> None:  # noqa: F811
    import os
    import signal

    from mixcount.run.scene_task import SceneTask, run_scene_task, stage_scene
    from mixcount.scene.sampler import sample_scene
    from mixcount.worker.contract import SceneOutputs
    from mixcount.worker.settle_ahead import SettleAheadWorker

    pool, assets = library
    cfg = _config()
    out = tmp_path / "out"
    spec = sample_scene(1, "train", cfg, pool)
    task = SceneTask(spec=spec, out_dir=str(out), assets_dir=str(assets), timeout_s=600, threads=2,
                     outputs=SceneOutputs.from_config(cfg.compose))
    staged = stage_scene(task)
    assert staged is not None
    with SettleAheadWorker(name="dies", log_dir=tmp_path) as worker:
        assert worker.begin_settle(staged.request)
        pid = worker.settler.pid
        assert pid
        os.kill(pid, signal.SIGKILL)  # it is loading the stage now
        outcome = run_scene_task(task, worker, staged)
        assert outcome.status == "written", outcome.error
        assert worker.settled_ahead == 0 and any("worker died" in f for f in worker.settle_failures)
    scene = out / "scenes" / spec.scene_id
    assert _diag(scene, "rest") and not _diag(scene, "settled_ahead")


class _FakeWorker:
    def __init__(self, k: int, log: list) -> None:
        self.k, self.log = k, log

    def close(self) -> None:
        pass


@pytest.mark.parametrize("size", [1, 2])
def test_pool_prefetches_the_next_job_on_the_worker_that_will_run_it(size: int) -> None:
    from mixcount.worker.pool import WorkerPool

    log: list[tuple[str, int, int]] = []
    lock = threading.Lock()

    def handle(worker: _FakeWorker, job: int) -> int:
        with lock:
            log.append(("run", worker.k, job))
        time.sleep(0.05)
        return job

    def prefetch(worker: _FakeWorker, job: int) -> None:
        with lock:
            log.append(("prefetch", worker.k, job))

    pool: WorkerPool[int, int] = WorkerPool(size, lambda k: _FakeWorker(k, log), recycle_after=0, handle=handle,
                                            on_error=lambda job, exc: -1, prefetch=prefetch)
    n, submitted, done = 12, 0, []
    while submitted < 2 * size:  # the caller keeps two jobs per worker in flight, as compose does
        pool.submit(submitted)
        submitted += 1
    while len(done) < n:
        done.append(pool.next_result(timeout=10))
        if submitted < n:
            pool.submit(submitted)
            submitted += 1
    pool.close()
    assert sorted(done) == list(range(n))
    runs = {job: k for what, k, job in log if what == "run"}
    fetched = {job: k for what, k, job in log if what == "prefetch"}
    assert len(fetched) >= n - 2 * size  # all but a slot's first jobs were seen ahead
    for job, k in fetched.items():
        assert runs[job] == k  # ... and ran on the worker that prefetched them
        assert log.index(("prefetch", k, job)) < log.index(("run", k, job))


def test_a_killed_pool_does_not_run_the_job_it_prefetched() -> None:
    from mixcount.worker.pool import WorkerPool

    ran: list[int] = []
    fetched = threading.Event()

    def handle(worker: _FakeWorker, job: int) -> int:
        ran.append(job)
        assert fetched.wait(5)  # the look-ahead holds job 1 while job 0 runs
        time.sleep(0.3)
        return job

    pool: WorkerPool[int, int] = WorkerPool(1, lambda k: _FakeWorker(k, []), recycle_after=0, handle=handle,
                                            on_error=lambda job, exc: -1, prefetch=lambda w, j: fetched.set())
    pool.submit(0)
    pool.submit(1)
    assert fetched.wait(5)
    pool.close(kill=True, join_s=5.0)
    time.sleep(0.5)
    assert ran == [0]
