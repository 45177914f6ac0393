"""The per-object work of the catalog steps (`catalog ingest`, `render`, `filter`, `caption`) as Ray tasks.

``--executor ray [--address HOST:PORT]`` on those commands opens a :class:`RayTasks` for the run
(:func:`catalog_executor`); the steps ask :func:`ray_tasks` and, when it answers one, hand their per-object
work to :meth:`RayTasks.map` instead of their local process / thread / bpy pools. Everything else stays in
the driver: the catalog (SQLite) is read and written by this one process only (it holds the writer lock),
results come back in the order of the work, so rows are written in the same order as locally and the
catalog is the same whichever executor ran it.

Failures: a task whose worker process or node dies is retried by Ray (``max_retries``, on any node); after
that it comes back as a :class:`TaskFailed` with its reason, which each step records as that object's
failure, as its local path records a crashed worker (the command then exits 3). The work functions catch
their own errors and return them as values, so an error of the input is never retried. A run that is
stopped goes on where it stopped because each step skips what the catalog already holds.

Files travel by paths the cluster shares (docs/ray.md): tasks get absolute paths (models, the catalog's
renders and descriptor folders) and read and write there. Nothing here imports Ray until a cluster is asked
for, so the local path needs no Ray.
"""

from __future__ import annotations

import contextlib
from typing import Any, Callable, Iterator, Optional, Sequence

from mixcount.catalog.step_executor import (
    TaskFailed,
    chunks,
    error_line,
    ray_tasks,
    release,
    run_and_collect,
    use_cluster,
)
from mixcount.errors import ExecutorError

__all__ = ["EXECUTORS", "RayTasks", "TaskFailed", "catalog_executor", "chunks", "ray_tasks", "task_error"]

EXECUTORS = ("local", "ray")
MAX_RETRIES = 2  # a task whose worker or node died runs again this many times, then fails its objects
MAX_ERROR_CHARS = 400

@contextlib.contextmanager
def catalog_executor(kind: str, address: Optional[str] = None, *,
                     max_retries: int = MAX_RETRIES) -> Iterator[Optional["RayTasks"]]:
    """``local``: nothing changes (yields None). ``ray``: connect to ``address`` (or start a private local
    cluster), make it the steps' :func:`ray_tasks` for the block, disconnect at the end."""
    if kind not in EXECUTORS:
        raise ExecutorError(f"unknown executor {kind!r} (expected one of {', '.join(EXECUTORS)})")
    if kind == "local":
        if address:
            raise ExecutorError("--address is for --executor ray")
        yield None
        return
    tasks = RayTasks(address, max_retries=max_retries)
    token = use_cluster(tasks)
    try:
        yield tasks
    finally:
        release(token)
        tasks.close()


class RayTasks:
    """A connection to a Ray cluster that maps module-level functions over work, one task per item."""

    def __init__(self, address: Optional[str], *, max_retries: int = MAX_RETRIES, connect_timeout_s: float = 120.0,
                 local_cpus: int = 2) -> None:
        try:
            import ray
        except ImportError as exc:  # pragma: no cover - ray is a pinned dependency
            raise ExecutorError("the ray executor needs the 'ray' package") from exc
        from mixcount.run.ray_executor import init_ray

        self._ray = ray
        self.max_retries = int(max_retries)
        self._own_init = False
        if not ray.is_initialized():
            init_ray(address, connect_timeout_s, local_cpus=local_cpus, object_store_mb=200)
            self._own_init = True
        self._remote: dict[Callable[..., Any], Any] = {}

    def cpus(self) -> int:
        """The cluster's CPUs now (the tasks in flight at once)."""
        return max(1, int(float(self._ray.cluster_resources().get("CPU", 1.0))))

    def put(self, value: Any) -> Any:
        """``value`` in the object store once (for what many tasks share), to pass as an argument."""
        return self._ray.put(value)

    def map(self, fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], *, window: int = 0) -> Iterator[Any]:
        """``fn(*a)`` for each ``a`` of ``args`` as Ray tasks (1 CPU each), results yielded in the order of
        ``args``; a task that could not finish after its retries yields a :class:`TaskFailed`. At most
        ``window`` tasks are queued at once (default: 4 per cluster CPU), so a long list does not fill the
        object store."""
        ray = self._ray
        remote = self._remote.get(fn)
        if remote is None:  # each task through step_executor.run_and_collect: a Ray worker lives for many tasks
            remote = self._remote[fn] = ray.remote(num_cpus=1, max_retries=self.max_retries, retry_exceptions=False,
                                                   name=getattr(fn, "__name__", "task"))(run_and_collect)
        window = window or 4 * self.cpus()
        refs: list[Any] = []
        sent = 0
        for k in range(len(args)):
            while sent < len(args) and sent < k + window:
                refs.append(remote.remote(fn, *args[sent]))
                sent += 1
            ref, refs[k] = refs[k], None  # the driver keeps no reference to what it has read
            try:
                yield ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - WorkerCrashedError, NodeDiedError, RayTaskError, ...
                yield TaskFailed(task_error(exc))

    def close(self) -> None:
        """Disconnect (and stop a cluster this started)."""
        if self._own_init and self._ray.is_initialized():
            self._ray.shutdown()


def task_error(exc: BaseException) -> str:
    """One line for a task that did not finish: the Ray error's type and first line."""
    return f"ray task failed after retries: {error_line(exc)}"[:MAX_ERROR_CHARS]
