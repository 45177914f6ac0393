"""The Ray executor on a REAL Ray cluster on 127.0.0.1 (``ray start --head`` in a subprocess, 2 CPUs).

* failure path with a trivial runner: a raising runner and a killed actor each fail exactly one scene,
  the restarted actor takes the next one, workers are recycled, the thread override reaches the task;
* quick scenes composed through ``mixcount compose --executor ray --address`` have the same COCO
  annotations as the local executor for the same seeds;
* a cluster killed (SIGKILL of every Ray process) mid-run leaves no partial scene, and a rerun against
  a fresh cluster completes the set with no duplicate.

Two clusters in all: the module's (``module_cluster``: the failure path, the clean compose run, then the run
killed with it) and the fresh one the killed run is resumed on.

Every Ray process a test starts is a descendant of its ``ray start --block`` process and is killed in a
``finally`` (not ``ray stop --force``, which would stop any other Ray on the machine); the test then
checks none is left.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import pytest

from mixcount.config import load_config
from mixcount.run.scene_task import FAILED, WRITTEN, SceneOutcome, SceneTask
from mixcount.worker.contract import SceneOutputs

pytestmark = [pytest.mark.ray]

PROJECT = Path(__file__).resolve().parent.parent
RAY = Path(sys.executable).parent / "ray"
MIX = Path(sys.executable).parent / "mixcount"
ENV = {**os.environ, "RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}


# ------------------------------------------------------------------------------------------ cluster


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        kids.setdefault(ppid, []).append(int(d.name))
    return kids


def _descendants(pid: int) -> set[int]:
    kids, out, todo = _children(), set(), [pid]
    while todo:
        p = todo.pop()
        for c in kids.get(p, []):
            if c not in out:
                out.add(c)
                todo.append(c)
    return out


def _start_time(pid: int) -> int | None:
    """Start time of ``pid`` (clock ticks since boot): tells a process from a later one with a reused pid."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


class Cluster:
    """One ``ray start --head --block`` on 127.0.0.1; ``kill()`` SIGKILLs it and every descendant."""

    def __init__(self, cpus: int = 2) -> None:
        self.port = _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.tmp = tempfile.mkdtemp(prefix="mcray", dir="/tmp")  # short: Ray's unix socket paths
        self.log = open(Path(self.tmp) / "head.log", "wb")
        self.proc = subprocess.Popen(
            [str(RAY), "start", "--head", "--block", "--node-ip-address", "127.0.0.1", "--port", str(self.port),
             "--num-cpus", str(cpus), "--include-dashboard=false", "--disable-usage-stats",
             "--object-store-memory", str(100 * 1024 * 1024), "--temp-dir", self.tmp],
            stdout=self.log, stderr=subprocess.STDOUT, env=ENV, start_new_session=True)
        self.seen: dict[int, int | None] = {}  # pid -> start time
        self.killed = False
        try:
            self._wait_ready()
        except BaseException:
            self.kill()
            raise

    def _wait_ready(self, timeout: float = 90.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"ray start exited: {(Path(self.tmp) / 'head.log').read_text()[-2000:]}")
            if b"Ray runtime started" in (Path(self.tmp) / "head.log").read_bytes():
                return
            time.sleep(0.5)
        raise RuntimeError("ray head did not start in time")

    def track(self) -> None:
        """Remember the current descendants (workers die with the raylet, but kill them too)."""
        for p in _descendants(self.proc.pid):
            self.seen.setdefault(p, _start_time(p))

    def kill(self) -> None:
        if self.killed:  # never signal recorded pids twice: they may have been reused meanwhile
            return
        self.killed = True
        self.track()
        pids = {p for p, t in self.seen.items() if _start_time(p) == t} | {self.proc.pid}
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)  # gcs, raylet, agents (the head's own session)
        for p in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(p, signal.SIGKILL)
        self.proc.wait(timeout=30)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(p) for p in pids):
            time.sleep(0.2)
        self.log.close()
        shutil.rmtree(self.tmp, ignore_errors=True)  # Ray's session files and logs

    def leftovers(self) -> list[int]:
        return [p for p, t in {**self.seen, self.proc.pid: None}.items()
                if _alive(p) and (t is None or _start_time(p) == t)]


@contextlib.contextmanager
def cluster(cpus: int = 2) -> Iterator[Cluster]:
    c = Cluster(cpus)
    try:
        yield c
    finally:
        c.kill()
        assert not c.leftovers(), f"Ray processes left running: {c.leftovers()}"


@pytest.fixture(scope="module")
def module_cluster() -> Iterator[Cluster]:
    """One cluster for the module's runs that leave it standing: the failure path's trivial tasks, then the
    clean compose run and the run killed with it (starting a head costs a few seconds of the suite each time).
    The test that kills it checks what it left itself; whatever still stands is killed and checked here."""
    with cluster() as c:
        yield c


# ------------------------------------------------------------------------------------------ failure path


@dataclass(frozen=True)
class FakeSpec:
    scene_id: str
    seed: int


class FakeWorker:
    def __init__(self, name: str, log_dir: Any) -> None:
        self.name = name
        self.pid = os.getpid()

    def close(self) -> None:
        pass


def fake_runner(task: SceneTask, worker: Any) -> SceneOutcome:
    """seed 1 raises, seed 2 kills its actor process, others succeed and report what they saw."""
    if task.spec.seed == 1:
        raise ValueError("planted failure")
    if task.spec.seed == 2:
        os._exit(3)
    return SceneOutcome(task.spec.scene_id, task.spec.seed, WRITTEN, 0.01, path=worker.name,
                        timings={"threads": float(task.threads)})


def test_failed_calls_fail_one_scene_each(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, module_cluster: Cluster) -> None:
    import ray
    import ray.cloudpickle

    from mixcount.run.ray_executor import RayExecutor

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # tests/ is not importable on workers
    tasks = [SceneTask(spec=FakeSpec(f"scene_{s:06d}", s), out_dir=str(tmp_path), assets_dir=str(tmp_path),
                       timeout_s=60, threads=2, outputs=SceneOutputs.from_config(load_config().compose)) for s in range(6)]
    missing = SceneTask(spec=FakeSpec("scene_000099", 99), out_dir=str(tmp_path / "nowhere"),
                        assets_dir=str(tmp_path), timeout_s=60, threads=2, outputs=SceneOutputs.from_config(load_config().compose))
    c = module_cluster  # left standing: the compose test below reuses it
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    ex = RayExecutor(address=c.address, slots=2, cpus_per_slot=1.0, threads=1, recycle_after=2, runner=fake_runner,
                     worker_factory=FakeWorker)
    try:
        assert ex.slots == 2
        for t in tasks + [missing]:
            ex.submit(t)
        outcomes = [ex.next_outcome(timeout=120) for _ in range(len(tasks) + 1)]
        c.track()
        info = ex.info()
    finally:
        ex.close()
        ray.shutdown()
    by_seed = {o.seed: o for o in outcomes}
    assert sorted(by_seed) == [0, 1, 2, 3, 4, 5, 99]  # every task answered once
    assert by_seed[1].status == FAILED and "planted failure" in (by_seed[1].error or "")
    assert by_seed[2].status == FAILED and "ray:" in (by_seed[2].error or "")  # the actor died
    assert by_seed[99].status == FAILED and "not visible on this node" in (by_seed[99].error or "")
    for s in (0, 3, 4, 5):  # the restarted actor kept working; the executor's thread count reached the task
        assert by_seed[s].status == WRITTEN and by_seed[s].timings["threads"] == 1.0
    assert all("scenes" in i for i in info), info
    assert sum(i["scenes"] for i in info) >= 4 and sum(i["recycled"] for i in info) >= 1


# ------------------------------------------------------------------------------------------ real scenes


@pytest.fixture(scope="module")
def demo_db(tmp_path_factory: pytest.TempPathFactory, demo_catalog_copy) -> Path:
    """A copy of the session's 12-object demo catalog (tests/conftest.py)."""
    return demo_catalog_copy(tmp_path_factory.mktemp("ray_demo"), 12) / "catalog.db"


def compose(db: Path, out: Path, n: int, *extra: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(MIX), "--db", str(db), "--config", "quick", "compose", "--n", str(n), "--out", str(out),
         "--resolution", "64", "--samples", "1", "--json", *extra], capture_output=True, text=True, env=ENV, timeout=timeout,
        cwd=PROJECT)


def annotations(out: Path) -> list[tuple[Any, ...]]:
    """Every COCO annotation as (scene_id, category, bbox, area, RLE counts, distractor, visibility)."""
    doc = json.loads((out / "annotations" / "instances_train.json").read_text())
    scene_of = {im["id"]: im["scene_id"] for im in doc["images"]}
    assert len(scene_of) == len(set(scene_of.values())), "duplicate image"
    return sorted((scene_of[a["image_id"]], a["category_id"], tuple(a["bbox"]), a["area"], a["segmentation"]["counts"],
                   a["is_distractor"], round(a["visibility"], 6)) for a in doc["annotations"])


@pytest.mark.blender
@pytest.mark.slow
def test_ray_cluster_matches_local_and_resumes_after_kill(demo_db: Path, tmp_path: Path, module_cluster: Cluster) -> None:
    n = 3
    local = compose(demo_db, tmp_path / "local", n, "--workers", "1")
    assert local.returncode == 0, local.stderr[-3000:]
    expected = annotations(tmp_path / "local")
    assert expected and len({a[0] for a in expected}) == n

    # 1) a clean run of n scenes through the cluster: same annotations as the local executor
    c = module_cluster
    assert not c.killed, "the module's cluster was killed before this test"
    run = compose(demo_db, tmp_path / "ray", n, "--executor", "ray", "--address", c.address, "--workers", "2")
    c.track()
    assert run.returncode == 0, run.stderr[-3000:]
    assert json.loads(run.stdout)["written"] == n
    assert annotations(tmp_path / "ray") == expected

    # 2) kill that cluster while the next run is going: no partial scene; a rerun on a new cluster completes the set
    out = tmp_path / "killed"
    try:
        driver = subprocess.Popen(
            [str(MIX), "--db", str(demo_db), "--config", "quick", "compose", "--n", str(n), "--out", str(out),
             "--resolution", "64", "--samples", "1", "--executor", "ray", "--address", c.address, "--workers", "2"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV, cwd=PROJECT, start_new_session=True)
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not list((out / "scenes").glob("scene_*/metadata.json")):
                c.track()
                time.sleep(0.2)
            c.kill()  # mid-run: the other slot is rendering
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(driver.pid, signal.SIGKILL)
            driver.wait(timeout=30)
    finally:
        c.kill()
    assert not c.leftovers(), f"Ray processes left running: {c.leftovers()}"
    done_before = sorted(p.parent.name for p in (out / "scenes").glob("scene_*/metadata.json"))
    assert 1 <= len(done_before) < n
    for d in (out / "scenes").glob("scene_*"):  # whatever is in place is complete
        assert (d / "metadata.json").is_file() and (d / "coco.json").is_file() and (d / "rgb.png").is_file()

    with cluster() as c:
        rerun = compose(demo_db, out, n, "--executor", "ray", "--address", c.address, "--workers", "2")
        c.track()
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    summary = json.loads(rerun.stdout)
    assert summary["written"] == n and summary["skipped"] == len(done_before)
    assert not list((out / "scenes").glob(".tmp-*")), "temporary scene folder left behind"
    assert sorted(p.name for p in (out / "scenes").glob("scene_*")) == sorted({a[0] for a in expected})
    assert annotations(out) == expected


def test_unreachable_address_fails_fast_with_a_clear_error() -> None:
    from mixcount.run.ray_executor import RayExecutor, RayExecutorError

    port = _free_port()  # nobody listens there: refused at once instead of Ray's minutes of GCS retries
    with pytest.raises(RayExecutorError, match=f"cannot reach the Ray cluster at 127.0.0.1:{port}"):
        RayExecutor(address=f"127.0.0.1:{port}", slots=1, cpus_per_slot=1.0, recycle_after=0)


def test_info_asks_a_restarting_actor_again() -> None:
    """The flake CI met: an actor Ray was restarting answered ActorUnavailableError to ``info``.

    A stand-in for Ray beside the real-cluster test above: the first answer is that error, the next the
    actor's record; ``info`` must return the record, and a dead actor's other errors as they are.
    """
    from ray.exceptions import ActorUnavailableError

    from mixcount.run.ray_executor import RayExecutor

    class Method:
        def __init__(self, answers: list[Any]) -> None:
            self.answers = answers

        def remote(self) -> Any:
            return self.answers.pop(0)

    class Actor:
        def __init__(self, answers: list[Any]) -> None:
            self.info = Method(answers)

    class FakeRay:
        def get(self, ref: Any, timeout: float) -> Any:
            if isinstance(ref, Exception):
                raise ref
            return ref

    ex = object.__new__(RayExecutor)
    ex._ray = FakeRay()
    ex._actors = [Actor([ActorUnavailableError("temporarily unavailable", None), {"scenes": 3}]),
                  Actor([RuntimeError("gone")])]
    info = ex.info(timeout=10)
    assert info[0] == {"scenes": 3}
    assert info[1] == {"error": "RuntimeError: gone"}
