"""The catalog steps on a REAL two-node Ray cluster on 127.0.0.1 (issue 69, item 2).

* a small demo library (seed 0, 2 ordinary objects, its traps and containers) ingested, rendered (64 px, 2
  spp), filtered and captioned with ``--executor ray --address`` gives the same catalog as the local
  executor: the same ``catalog list --json`` documents (objects, facts, flags with their reasons, statuses,
  captions), timestamps and absolute paths aside; the render step's second node is SIGKILLed while one of
  its render tasks runs, and the run still finishes (Ray runs the lost task again on the head); run again,
  the render has nothing left to do;
* a task whose process dies on every try comes back as a failure with its reason, and ingest records such
  an object as the run's failure (exit 3 in the CLI, as a crashed local worker).

One cluster for the module: a head and a second node (``ray start --address``), 1 CPU each, so the tasks of
one step are shared between the two nodes. Every Ray process started is killed by pid (see
tests/test_ray_executor.py, whose ``Cluster`` starts the head).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

from tests.test_ray_executor import ENV, MIX, RAY, Cluster, _alive, _descendants, _start_time

pytestmark = [pytest.mark.ray]

OPTS = ["--config", "configs/quick.toml", "--set", "canonical_render.resolution=64", "--set",
        "canonical_render.samples=2"]
VOLATILE = ("created_at", "updated_at", "ingest_run_id")  # when, and which run: not what the catalog says


class Node:
    """A second node: ``ray start --address HEAD --block`` (1 CPU); ``kill()`` SIGKILLs it and its workers."""

    def __init__(self, head: Cluster) -> None:
        self.log = open(Path(head.tmp) / "node.log", "wb")
        self.proc = subprocess.Popen(
            [str(RAY), "start", "--address", head.address, "--block", "--num-cpus", "1", "--disable-usage-stats",
             "--object-store-memory", str(100 * 1024 * 1024)],
            stdout=self.log, stderr=subprocess.STDOUT, env=ENV, start_new_session=True)
        self.seen: dict[int, int | None] = {}
        deadline = time.monotonic() + 90
        while b"Ray runtime started" not in (Path(head.tmp) / "node.log").read_bytes():
            assert self.proc.poll() is None and time.monotonic() < deadline, (Path(head.tmp) / "node.log").read_text()
            time.sleep(0.5)

    def running(self, name: str) -> bool:
        """Whether one of this node's worker processes runs task ``name`` now (its title is ``ray::name``)."""
        for p in _descendants(self.proc.pid):
            self.seen.setdefault(p, _start_time(p))
            with contextlib.suppress(OSError):
                if Path(f"/proc/{p}/cmdline").read_bytes().startswith(f"ray::{name}".encode()):
                    return True
        return False

    def kill(self) -> None:
        self.running("")
        pids = {p for p, t in self.seen.items() if _start_time(p) == t} | {self.proc.pid}
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        for p in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(p, signal.SIGKILL)
        self.proc.wait(timeout=30)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(p) for p in pids):
            time.sleep(0.2)
        self.log.close()
        assert not [p for p in pids if _alive(p)]


@pytest.fixture(scope="module")
def two_nodes() -> Iterator[tuple[Cluster, Node]]:
    head = Cluster(cpus=1)
    node = None
    try:
        node = Node(head)
        yield head, node
    finally:
        if node is not None and node.proc.poll() is None:
            node.kill()
        head.kill()
        assert not head.leftovers()


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from mixcount.demo.library import generate_demo_library

    root = tmp_path_factory.mktemp("raycat") / "lib"
    generate_demo_library(root, seed=0, n_objects=2)
    return root


def mix(db: Path, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(MIX), "--db", str(db), *OPTS, *args], capture_output=True, text=True,
                          env=env or ENV, cwd=Path(__file__).resolve().parent.parent, timeout=600)


def documents(db: Path) -> list[dict[str, Any]]:
    """``catalog list --json`` with the run's timestamps dropped and the catalog's own folder as ``DB``."""
    got = mix(db, "catalog", "list", "--json")
    assert got.returncode == 0, got.stderr
    text = got.stdout.replace(str(db.parent), "DB")
    return [{k: v for k, v in o.items() if k not in VOLATILE} for o in json.loads(text)]


def test_ray_catalog_is_the_local_catalog_with_a_node_killed(two_nodes: tuple[Cluster, Node], library: Path,
                                                             tmp_path: Path) -> None:
    head, node = two_nodes
    local, ray = tmp_path / "local" / "catalog.db", tmp_path / "ray" / "catalog.db"
    for db in (local, ray):
        db.parent.mkdir()
    on_ray = ["--executor", "ray", "--address", head.address]
    for step in (["ingest", str(library)], ["render"], ["filter"], ["caption"]):
        got = mix(local, "catalog", *step)
        assert got.returncode == 0, got.stderr[-2000:]
    assert mix(ray, "catalog", "ingest", str(library), *on_ray).returncode == 0

    # render: the second node dies while it runs a render task; the run finishes on the head
    proc = subprocess.Popen([str(MIX), "--db", str(ray), *OPTS, "catalog", "render", *on_ray], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parent.parent)
    try:
        deadline = time.monotonic() + 300
        while not node.running("render_chunk"):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no render task ever ran on the second node"
            time.sleep(0.2)
        node.kill()
        out, err = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    assert " 0 failed" in out + err
    for step in (["filter"], ["caption"]):
        got = mix(ray, "catalog", *step, *on_ray)
        assert got.returncode == 0, got.stderr[-2000:]

    again = mix(ray, "catalog", "render", *on_ray)  # run again: goes on where the catalog is (nothing left)
    assert again.returncode == 0 and " 0 rendered" in again.stdout + again.stderr

    a, b = documents(local), documents(ray)
    assert len(a) == len(b) >= 10
    assert sum(len(o["flags"]) for o in a) > 0 and sum(1 for o in a if o["captions"]) > 0
    assert [o["status"] for o in a] == [o["status"] for o in b]
    assert [o["flags"] for o in a] == [o["flags"] for o in b]
    assert [o["captions"] for o in a] == [o["captions"] for o in b]
    assert a == b


def die_on_two(k: int) -> int:
    """A task that kills its own worker process for k == 2 (every try), else answers k * 10."""
    if k == 2:
        os._exit(7)
    return k * 10


def test_a_task_that_dies_on_every_try_is_a_failure_with_its_reason(two_nodes: tuple[Cluster, Node]) -> None:
    import ray.cloudpickle

    from mixcount.run.catalog_tasks import TaskFailed, catalog_executor

    head, _node = two_nodes
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    old = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"
    try:
        with catalog_executor("ray", head.address, max_retries=1) as cluster:
            assert cluster is not None
            got = list(cluster.map(die_on_two, [(1,), (2,), (3,)]))
    finally:
        if old is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = old
    assert got[0] == 10 and got[2] == 30
    assert isinstance(got[1], TaskFailed) and "ray task failed after retries" in got[1].error
    assert "WorkerCrashedError" in got[1].error or "died" in got[1].error


def test_an_analysis_lost_on_the_cluster_is_the_runs_failure(monkeypatch: pytest.MonkeyPatch) -> None:
    """What analyse_all records for a TaskFailed: a reason ingest counts as the run's failure (exit 3)."""
    from mixcount.catalog import analysis_pool, step_executor
    from mixcount.catalog.ingest_runs import run_failure

    class Lost:
        def map(self, fn: Any, args: list[tuple[Any, ...]]) -> Iterator[Any]:
            assert fn is analysis_pool.run_analysis
            yield from [({"faces": 1}, None), step_executor.TaskFailed("ray task failed after retries: NodeDiedError: x")]

    monkeypatch.setattr(step_executor, "ray_tasks", lambda: Lost())
    seen: list[tuple[str, Any, Any]] = []
    analysis_pool.analyse_all([("a", {}), ("b", {})], 2, lambda job, facts, error: seen.append((job, facts, error)))
    assert seen[0] == ("a", {"faces": 1}, None)
    assert seen[1][0] == "b" and seen[1][1] is None and run_failure(seen[1][2]) and "NodeDiedError" in seen[1][2]
