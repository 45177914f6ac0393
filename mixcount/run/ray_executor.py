"""Ray executor: the same interface as :class:`~mixcount.run.local.LocalExecutor`, on a Ray cluster.

``RayExecutor(address=None, slots=K)`` connects to an existing cluster (``ray.init(address=...)``) or,
without an address, starts a small local one on 127.0.0.1. It keeps ``slots`` *actors*; each actor owns
one long-lived :class:`~mixcount.worker.client.BlenderWorker` subprocess (bpy starts once per actor, not
once per scene, and still never runs inside a Ray worker process itself). One actor call = one scene:

* at most ``slots`` scenes are in flight (one per actor); further ``submit`` s wait in a local queue;
* ``next_outcome`` returns outcomes in completion order (``ray.wait``);
* a failed call fails one scene: a Ray error (task error, actor or node death, lost object, a call that
  overran the scene timeout) becomes a :class:`~mixcount.run.scene_task.SceneOutcome` with status
  "failed"; the actor is restarted by Ray (``max_restarts=-1``) and takes the next scene. Calls are never
  retried by Ray (``max_task_retries=0``): a rerun of ``compose`` redoes missing scenes, and the writer's
  temporary-folder-then-rename keeps a half-done scene out of OUT;
* each actor recycles its BlenderWorker after ``recycle_after`` scenes (``[compose].recycle_after``) so
  the bpy process's memory stays flat over long runs.

Files, not objects, carry the data: a :class:`~mixcount.run.scene_task.SceneTask` holds absolute paths
(the output folder and the converted USD assets), and the actor writes the finished scene folder there.
Every node must therefore see the same paths (a shared filesystem: NFS, a cloud bucket mounted with the
same path, ...) and have the same Python environment (see docs/ray.md). An actor checks that the task's
output folder exists on its node and fails the scene with a clear message otherwise.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import queue
import socket
import tempfile
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable, Optional

from mixcount.errors import ExecutorError
from mixcount.run.scene_task import FAILED, SceneOutcome, SceneRunner, SceneTask, run_scene_task
from mixcount.worker.pool import MAX_ERROR_CHARS, WorkerSlot, error_text

#: seconds a call may run beyond its task's ``timeout_s`` before the driver gives up on the actor
CALL_GRACE_S = 120.0


RayExecutorError = ExecutorError  # the name this module has always raised (mixcount.errors.ExecutorError)


def default_worker_factory(name: str, log_dir: Optional[str], cpu_threads: int = 0) -> Any:
    """A :class:`BlenderWorker` logging under ``log_dir`` when this node can write there, else the temp dir,
    started for ``cpu_threads`` render threads (0: all of the node's)."""
    from mixcount.worker.client import BlenderWorker

    path: Optional[Path] = None
    if log_dir:
        try:
            Path(log_dir).mkdir(parents=True, exist_ok=True)
            path = Path(log_dir)
        except OSError:
            path = None
    return BlenderWorker(name=name, log_dir=path or Path(tempfile.gettempdir()), cpu_threads=cpu_threads)


def failed_outcome(task: SceneTask, error: str, seconds: float = 0.0) -> SceneOutcome:
    return SceneOutcome(task.spec.scene_id, task.spec.seed, FAILED, seconds, error=error[:MAX_ERROR_CHARS])


class SceneActor:
    """Body of the Ray actor (wrapped with ``ray.remote`` lazily, so importing this module needs no Ray)."""

    def __init__(self, name: str, *, recycle_after: int, log_dir: Optional[str] = None,
                 runner: SceneRunner = run_scene_task,
                 worker_factory: Callable[[str, Optional[str]], Any] = default_worker_factory) -> None:
        self.name = name
        self.log_dir = log_dir
        self.runner = runner
        # one BlenderWorker, recycled after recycle_after scenes: the pool's one rule
        self.slot = WorkerSlot(lambda: worker_factory(f"{self.name}-{os.getpid()}", self.log_dir),
                               recycle_after=recycle_after)

    def run(self, task: SceneTask) -> SceneOutcome:
        t0 = time.perf_counter()
        # the asset folder may not exist yet (assets are converted on first use), the output folder must
        if not Path(task.out_dir).is_dir():
            return failed_outcome(task, f"{self.name} on {socket.gethostname()}: output folder {task.out_dir} is "
                                        "not visible on this node; every node needs the output, asset and model "
                                        "folders at the same paths (shared filesystem, see docs/ray.md)")
        try:
            return self.slot.run(lambda worker: self.runner(task, worker))
        except Exception as exc:  # noqa: BLE001 - a runner that raises fails one scene
            return failed_outcome(task, error_text(exc), time.perf_counter() - t0)

    def info(self) -> dict[str, Any]:
        w = self.slot.current
        pid = getattr(w, "pid", None) if w is not None else None
        return {"name": self.name, "host": socket.gethostname(), "pid": os.getpid(), "worker_pid": pid,
                "worker_rss_kb": _rss_kb(pid), "scenes": self.slot.total, "recycled": self.slot.recycled}

    def close(self) -> bool:
        self.slot.close()
        return True


def cluster_device(device: Optional[str], cluster_gpus: float, gpus_per_slot: float) -> Any:
    """``compose.device`` on a Ray cluster with ``cluster_gpus`` GPU resources: a
    :class:`~mixcount.run.devices.RunDevice` ("gpu": each actor reserves ``gpus_per_slot``; Ray sets its
    CUDA_VISIBLE_DEVICES, which its bpy worker inherits). ``gpu`` on a cluster without a GPU resource is an
    ExecutorError (one line, before any scene is sent); ``auto`` then renders on the CPU, said once."""
    from mixcount.run.devices import RunDevice

    if device in (None, "cpu"):
        return RunDevice("cpu", None, None)
    if cluster_gpus >= gpus_per_slot > 0:
        return RunDevice("gpu", None, f"rendering on the Ray cluster's GPUs: {cluster_gpus:g} GPU(s), "
                                      f"{gpus_per_slot:g} per scene actor")
    if device == "gpu":
        raise RayExecutorError(f"compose.device = \"gpu\" but the Ray cluster has {cluster_gpus:g} GPU(s) and each "
                               f"scene actor asks for {gpus_per_slot:g} (compose.ray_gpus_per_worker); start the "
                               "nodes with GPUs (`ray start --num-gpus N`) or use --device cpu or auto; nothing "
                               "was written")
    return RunDevice("cpu", None, "compose.device = \"auto\": the Ray cluster has no GPU resource: rendering on "
                                  "the CPU")


H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"  # preface, empty SETTINGS
PROBE_S = 10.0  # the most the probe of a cluster address waits, connect to answer


def probe_address(address: str, timeout: float) -> None:
    """Fail fast, within :data:`PROBE_S`, on a ``host:port`` that is not a Ray cluster's GCS: nobody listens
    (ray.init would retry for minutes), or something listens but does not answer as a gRPC (HTTP/2) server
    (a silent port, the dashboard's HTTP port): ray.init then retried for ever (over 400 s seen) with no
    word. The probe sends HTTP/2's client preface and waits for the server's SETTINGS frame, under one
    deadline for the connect and every read."""
    host, sep, port = address.rpartition(":")
    if not sep or "://" in address or not port.isdigit():
        return  # "auto", "ray://..." (Ray Client): let Ray handle them
    wait = min(timeout, PROBE_S)
    deadline = time.monotonic() + wait
    head = b""
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=wait) as sock:
            sock.sendall(H2_PREFACE)
            while len(head) < 9 and (left := deadline - time.monotonic()) > 0:
                sock.settimeout(left)
                chunk = sock.recv(9 - len(head))
                if not chunk:
                    break
                head += chunk
    except socket.timeout:
        pass
    except OSError as exc:
        raise RayExecutorError(f"cannot reach the Ray cluster at {address}: {exc} (is `ray start --head` running "
                               "there, and the port open?)") from None
    if len(head) < 9 or head[3] != 0x4:  # HTTP/2 frame header: length (3), type (4 = SETTINGS), flags, stream
        raise RayExecutorError(
            f"{address} is not a Ray cluster: something listens there but sent nothing a Ray GCS (a gRPC server) sends within "
            f"{wait:g} s; give the head's address as `ray start --head` prints it (port 6379 by default), not the "
            "dashboard's")


_probe = probe_address  # the name tests/test_captions_deadline.py calls


def init_ray(address: Optional[str], connect_timeout_s: float, *, local_cpus: int, object_store_mb: int) -> None:
    """``ray.init`` for this driver, shared by compose's and the catalog steps' executors: the cluster at
    ``address`` (probed first: a port that is no Ray GCS fails in one line) or, without one, a private local
    cluster of ``local_cpus`` CPUs. Called from the package's folder, since Ray puts the driver's current
    folder first on its workers' ``sys.path``; any failure is one :class:`ExecutorError` line."""
    import logging

    import ray

    from mixcount.stop_signals import keep_ours_over
    from mixcount.worker.client import in_package_root

    kwargs: dict[str, Any] = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING,
                                  configure_logging=True)
    if address:
        probe_address(address, connect_timeout_s)
    try:
        with in_package_root(), keep_ours_over():  # ray.init sets SIGTERM to sys.exit(15): ours stops as Ctrl-C
            if address:
                ray.init(address=address, **kwargs)
            else:
                ray.init(num_cpus=local_cpus, _node_ip_address="127.0.0.1",
                         object_store_memory=object_store_mb * 1024 * 1024, **kwargs)
    except Exception as exc:  # noqa: BLE001 - ConnectionError, RuntimeError, ...: one clear message
        where = f"reach the Ray cluster at {address}" if address else "start a local Ray cluster"
        raise RayExecutorError(f"cannot {where}: {type(exc).__name__}: {exc}") from exc


def _rss_kb(pid: Optional[int]) -> Optional[int]:
    """Resident memory of ``pid`` in KiB from /proc (None where unknown)."""
    if not pid:
        return None
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


class RayExecutor:
    """``slots`` scene actors on a Ray cluster (see the module docstring)."""

    def __init__(self, address: Optional[str] = None, slots: Optional[int] = None, *, cpus_per_slot: float,
                 threads: Optional[int] = None, recycle_after: int, log_dir: Optional[Path] = None,
                 runner: SceneRunner = run_scene_task,
                 worker_factory: Callable[[str, Optional[str]], Any] = default_worker_factory,
                 object_store_mb: int = 200, connect_timeout_s: float = 120.0, device: Optional[str] = None,
                 gpus_per_slot: float = 1.0) -> None:
        try:
            import ray
        except ImportError as exc:  # pragma: no cover - ray is a pinned dependency
            raise RayExecutorError("the ray executor needs the 'ray' package") from exc

        self._ray = ray
        self.address = address
        self.threads = threads
        self._own_init = False
        if not ray.is_initialized():
            if slots or device in (None, "cpu"):
                n = max(1, int(slots or 1))
            else:  # GPU actors, as many as GPUs: CPUs for all of them
                n = max(1, (os.cpu_count() or 1) // max(1, int(cpus_per_slot)))
            init_ray(address, connect_timeout_s, local_cpus=max(1, int(round(n * cpus_per_slot))),
                     object_store_mb=int(object_store_mb))
            self._own_init = True
        try:
            self.device = cluster_device(device, float(ray.cluster_resources().get("GPU", 0.0)), gpus_per_slot)
        except RayExecutorError:
            if self._own_init:
                ray.shutdown()
            raise
        gpus = gpus_per_slot if self.device.device == "gpu" else 0.0
        if slots is None:
            cpus = float(ray.cluster_resources().get("CPU", 1.0))
            slots = max(1, int(cpus // cpus_per_slot))
            if gpus:  # one actor per GPU share (compose.ray_gpus_per_worker), as CPUs allow
                slots = max(1, min(slots, int(float(ray.cluster_resources().get("GPU", 0.0)) // gpus)))
        self.slots = max(1, int(slots))
        remote_cls = ray.remote(num_cpus=cpus_per_slot, num_gpus=gpus, max_restarts=-1,
                                max_task_retries=0)(SceneActor)
        self._actors = [remote_cls.remote(f"ray{k}", recycle_after=recycle_after,
                                          log_dir=str(log_dir) if log_dir else None, runner=runner,
                                          worker_factory=self._sized(worker_factory, threads))
                        for k in range(self.slots)]
        self._idle: deque[int] = deque(range(self.slots))
        self._pending: deque[SceneTask] = deque()
        self._inflight: dict[Any, tuple[SceneTask, int, float]] = {}  # ref -> (task, actor index, start)
        self._ready: deque[SceneOutcome] = deque()
        self.connect_timeout_s = connect_timeout_s

    @staticmethod
    def _sized(factory: Callable[..., Any], threads: Optional[int]) -> Callable[..., Any]:
        """The default worker factory bound to the threads every task is given (a caller's own as it is)."""
        if factory is default_worker_factory and threads:
            return functools.partial(default_worker_factory, cpu_threads=int(threads))
        return factory

    # -------------------------------------------------------------------------------- interface

    def submit(self, task: SceneTask) -> None:
        if self.threads:
            task = dataclasses.replace(task, threads=int(self.threads))
        task = dataclasses.replace(task, device=self.device.device)
        self._pending.append(task)
        self._dispatch()

    def _dispatch(self) -> None:
        while self._idle and self._pending:
            k = self._idle.popleft()
            task = self._pending.popleft()
            ref = self._actors[k].run.remote(task)
            self._inflight[ref] = (task, k, time.monotonic())

    def next_outcome(self, timeout: Optional[float] = None) -> SceneOutcome:
        """The next finished scene (completion order). Raises ``queue.Empty`` after ``timeout`` seconds."""
        ray = self._ray
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._ready:
            if not self._inflight:
                raise queue.Empty
            wait_s = 5.0 if deadline is None else max(0.0, min(5.0, deadline - time.monotonic()))
            done, _ = ray.wait(list(self._inflight), num_returns=1, timeout=wait_s)
            for ref in done:
                task, k, started = self._inflight.pop(ref)
                self._ready.append(self._collect(ref, task, time.monotonic() - started))
                self._idle.append(k)
            self._expire_overdue()
            self._dispatch()
            if not self._ready and deadline is not None and time.monotonic() >= deadline:
                raise queue.Empty
        return self._ready.popleft()

    def _collect(self, ref: Any, task: SceneTask, seconds: float) -> SceneOutcome:
        try:
            outcome = self._ray.get(ref)
        except Exception as exc:  # noqa: BLE001 - RayTaskError, ActorDiedError, WorkerCrashedError, ObjectLostError...
            return failed_outcome(task, f"ray: {type(exc).__name__}: {str(exc).strip()}", seconds)
        if not isinstance(outcome, SceneOutcome):
            return failed_outcome(task, f"ray: unexpected result {type(outcome).__name__}", seconds)
        return outcome

    def _expire_overdue(self) -> None:
        """Fail (and restart the actor of) calls that ran far past their scene timeout: a hung actor."""
        now = time.monotonic()
        for ref, (task, k, started) in list(self._inflight.items()):
            if now - started > float(task.timeout_s) + CALL_GRACE_S:
                del self._inflight[ref]
                try:
                    self._ray.kill(self._actors[k], no_restart=False)
                except Exception:  # noqa: BLE001
                    pass
                self._ready.append(failed_outcome(task, f"ray: call overran {task.timeout_s:.0f} s + "
                                                        f"{CALL_GRACE_S:.0f} s grace; actor restarted", now - started))
                self._idle.append(k)

    def info(self, timeout: float = 30.0) -> list[dict[str, Any]]:
        """Per-actor host, pids, scenes done, recycles and worker memory (for benchmarks and logs).

        An actor Ray is restarting answers ``ActorUnavailableError`` for a moment; ``info`` has no side
        effects, so it asks that actor again until ``timeout`` rather than report a transient error.
        """
        from ray.exceptions import ActorUnavailableError

        deadline = time.monotonic() + timeout
        refs = [a.info.remote() for a in self._actors]
        out: list[dict[str, Any]] = []
        for actor, ref in zip(self._actors, refs):
            while True:
                try:
                    out.append(self._ray.get(ref, timeout=max(0.1, deadline - time.monotonic())))
                except ActorUnavailableError as exc:
                    if time.monotonic() < deadline:
                        time.sleep(0.5)
                        ref = actor.info.remote()
                        continue
                    out.append({"error": f"{type(exc).__name__}: {exc}"})
                except Exception as exc:  # noqa: BLE001
                    out.append({"error": f"{type(exc).__name__}: {exc}"})
                break
        return out

    def close(self) -> None:
        """Stop the bpy workers and the actors; disconnect (and stop a cluster this executor started)."""
        ray = self._ray
        if not ray.is_initialized():
            return
        try:
            refs = [a.close.remote() for a in self._actors]
            ray.wait(refs, num_returns=len(refs), timeout=30)
        except Exception:  # noqa: BLE001 - a dead cluster: nothing left to close
            pass
        for a in self._actors:
            try:
                ray.kill(a, no_restart=True)
            except Exception:  # noqa: BLE001
                pass
        self._actors = []
        if self._own_init:
            ray.shutdown()

    def __enter__(self) -> "RayExecutor":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
