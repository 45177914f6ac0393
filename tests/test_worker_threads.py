"""A bpy worker's TBB is sized to the threads its renders use (mixcount.engine.worker_main.import_bpy), and
it frees each request's reference cycles before the next request.

oneTBB reads its concurrency once, from the CPU affinity mask, when bpy starts; a worker that renders with
fewer Cycles threads than the machine has cores otherwise keeps a TBB thread spinning in ``sched_yield`` on
every other core for the whole render (docs/blender.md). These tests start real workers and read the
concurrency back from bpy's own libtbb; the executors' plumbing is checked with runners that start nothing.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path
from typing import Any

import pytest

from mixcount.config import load_config
from mixcount.run.scene_task import WRITTEN, SceneOutcome, SceneTask
from mixcount.worker.client import THREADS_ENV, BlenderWorker
from mixcount.worker.contract import SceneOutputs

CPUS = sorted(os.sched_getaffinity(0))


@pytest.mark.skipif(len(CPUS) < 2, reason="one CPU: nothing to size TBB below the machine")
def test_a_worker_for_one_thread_imports_bpy_with_tbb_at_one_and_keeps_every_cpu(tmp_path: Path) -> None:
    with BlenderWorker(name="one", log_dir=tmp_path, cpu_threads=1) as one, \
            BlenderWorker(name="all", log_dir=tmp_path) as every:
        one_ping = one.request({"op": "ping"}, timeout=180)
        all_ping = every.request({"op": "ping"}, timeout=180)
        assert one_ping["tbb_concurrency"] == 1
        assert all_ping["tbb_concurrency"] == len(CPUS)
        # held to one CPU for the import only: the worker may run on any of them afterwards
        assert sorted(os.sched_getaffinity(one_ping["pid"])) == CPUS


def test_a_workers_thread_count_is_never_inherited(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A parent that is itself a sized worker (its environment holds the variable) starts all-core workers
    unless told otherwise: the setting belongs to the worker object, not to the environment."""
    monkeypatch.setenv(THREADS_ENV, "1")
    with BlenderWorker(name="plain", log_dir=tmp_path) as plain:
        assert plain.request({"op": "ping"}, timeout=180)["tbb_concurrency"] == len(CPUS)


def test_a_worker_frees_what_one_request_left_in_cycles_before_the_next(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker lives for many objects: what a request built in reference cycles is collected before its
    answer goes (``worker_main.main``), so the next request starts from one object's memory."""
    monkeypatch.setattr("mixcount.worker.client.WORKER_MODULE", "tests.fault_worker")
    with BlenderWorker(name="cycles", log_dir=tmp_path, cpu_threads=1) as worker:
        alive = [worker.request({"op": "leave_cycle"}, timeout=180)["alive"] for _ in range(4)]
    assert alive == [0, 0, 0, 0]


@dataclasses.dataclass(frozen=True)
class _Spec:
    scene_id: str
    seed: int


def _task(seed: int, threads: int) -> SceneTask:
    return SceneTask(spec=_Spec(f"scene_{seed:06d}", seed), out_dir="o", assets_dir="a", timeout_s=5.0,  # type: ignore[arg-type]
                     threads=threads, outputs=SceneOutputs.from_config(load_config().compose))


def _recording_runner(seen: list[tuple[int, int]]) -> Any:
    def runner(task: SceneTask, worker: Any) -> SceneOutcome:  # the worker is never started
        seen.append((task.threads, worker.cpu_threads))
        return SceneOutcome(task.spec.scene_id, task.spec.seed, WRITTEN, 0.0)
    return runner


def test_the_local_executor_starts_its_workers_for_the_threads_its_scenes_render_with() -> None:
    from mixcount.run.local import LocalExecutor

    seen: list[tuple[int, int]] = []
    with LocalExecutor(2, runner=_recording_runner(seen), recycle_after=0, settle_ahead=False, cpu_threads=1) as ex:
        for seed in range(4):
            ex.submit(_task(seed, threads=7))  # the executor's count replaces the task's
        outcomes = [ex.next_outcome(timeout=30) for _ in range(4)]
    assert all(o.status == WRITTEN for o in outcomes)
    assert seen == [(1, 1)] * 4

    from mixcount.worker.settle_ahead import SettleAheadWorker

    pair = SettleAheadWorker(name="pair", cpu_threads=1)
    assert (pair.render.cpu_threads, pair.settler.cpu_threads) == (1, 1)
    assert SettleAheadWorker(name="pair", cpu_threads=0).settler.cpu_threads == 1  # Bullet: one thread, always


def test_make_executor_sizes_local_workers_as_compose_sizes_its_scenes() -> None:
    from mixcount.run.compose import render_threads
    from mixcount.run.factory import make_executor

    comp = load_config(values={"compose.workers": 2, "compose.render_threads": 0}).compose
    with make_executor("local", None, None, config=comp, runner=_recording_runner([])) as ex:
        assert ex.cpu_threads == render_threads(0, 2) == max(1, (os.cpu_count() or 1) // 2)
    with make_executor("local", 1, None, config=comp, runner=_recording_runner([])) as ex:
        assert ex.cpu_threads == render_threads(0, 1) == (os.cpu_count() or 1)


def test_the_ray_executor_binds_its_thread_count_to_the_default_worker_factory_only() -> None:
    from mixcount.run.ray_executor import RayExecutor, default_worker_factory

    bound = RayExecutor._sized(default_worker_factory, 2)
    assert isinstance(bound, functools.partial) and bound.keywords == {"cpu_threads": 2}
    assert bound("w", None).cpu_threads == 2  # a BlenderWorker object; nothing is started
    own = lambda name, log_dir: None  # noqa: E731
    assert RayExecutor._sized(own, 2) is own
    assert RayExecutor._sized(default_worker_factory, None) is default_worker_factory
