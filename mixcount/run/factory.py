"""``make_executor(kind, ...)``: the one place that turns ``--executor local|ray [--address]`` into an executor.

Both kinds take the same ``[compose]`` keys: ``workers`` (slots), ``render_threads`` (Cycles threads per
worker; 0 = CPUs / workers locally, the actor's CPU share on Ray) and ``recycle_after`` (restart a bpy
worker after that many scenes; 0 = never). The local one also reads ``settle_ahead`` (a companion bpy
process per worker settles the next scene during the current render), Ray ``ray_cpus_per_worker`` and, with
``device`` gpu or auto, ``ray_gpus_per_worker`` (without ``--workers``: one actor per that many GPUs).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from mixcount.config import ComposeConfig
from mixcount.errors import MixcountError
from mixcount.run.local import Executor

EXECUTORS = ("local", "ray")


def make_executor(kind: str = "local", workers: Optional[int] = None, address: Optional[str] = None, *,
                  config: ComposeConfig, log_dir: Optional[Path] = None, **extra: Any) -> Executor:
    """A started executor of ``kind`` ("local" or "ray"); close it (or use ``with``) when done.

    ``config``: the ``[compose]`` section. ``workers`` (None: ``compose.workers``) sets the slots; on a Ray
    cluster given by ``address``, None means every CPU of the cluster divided by ``ray_cpus_per_worker``.
    ``extra`` goes to the executor class.
    """
    comp = config
    recycle = comp.recycle_after
    kind = (kind or "local").lower()
    if kind == "local":
        if address:
            raise MixcountError("--address is only used with --executor ray")
        from mixcount.run.compose import render_threads
        from mixcount.run.local import LocalExecutor

        n = workers or comp.workers
        return LocalExecutor(n, log_dir=log_dir, recycle_after=recycle, settle_ahead=comp.settle_ahead,
                             **{"cpu_threads": render_threads(comp.render_threads, n), **extra})
    if kind == "ray":
        from mixcount.run.ray_executor import RayExecutor

        cpus = float(comp.ray_cpus_per_worker)
        threads = comp.render_threads or max(1, int(round(cpus)))
        slots = workers if workers else (None if address else comp.workers)
        if comp.device != "cpu" and not workers:
            slots = None  # one actor per GPU share of the cluster (compose.ray_gpus_per_worker)
        return RayExecutor(address=address, slots=slots, cpus_per_slot=cpus, threads=threads,
                           recycle_after=recycle, log_dir=log_dir, device=comp.device,
                           gpus_per_slot=float(comp.ray_gpus_per_worker), **extra)
    raise MixcountError(f"unknown executor {kind!r}: choose one of {', '.join(EXECUTORS)}")
