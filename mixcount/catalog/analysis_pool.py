"""Step 3 of `catalog ingest`: the mesh analysis of many models (:func:`mixcount.catalog.mesh.analyse_model`),
in a process pool when more than one worker is set, each result handed to the caller in the order of the jobs.

Kept apart from :mod:`mixcount.catalog.ingest` (which stores each result) because it is the one part that
deals with processes: a worker that dies (segfault, OOM kill) takes its pool with it, so the models it held
are retried one per fresh process, and the one that crashes is the one recorded as broken."""

from __future__ import annotations

from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Callable, TypeVar

from mixcount.catalog.layouts import Candidate
from mixcount.errors import IngestError
from mixcount.frame import GLTF_EXTENSIONS, GLTF_UP_AXIS
from mixcount.task_memory import forked_worker_start

Job = TypeVar("Job")
Facts = tuple[dict[str, Any] | None, str | None]  # (facts, None) or (None, why the model is broken)


def analysis_kwargs(cand: Candidate, catalog_collision_dir: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`mixcount.catalog.mesh.analyse_model` for one candidate."""
    return {
        "model_path": str(cand.model_path),
        "collision_dir": str(catalog_collision_dir),
        "face_budget": settings["collision_face_budget"],
        "units": (cand.units or settings["assume_units"]),
        "units_reason": cand.units_reason or "",
        "up_axis": (cand.up_axis or (GLTF_UP_AXIS if Path(str(cand.model_path)).suffix.lower() in GLTF_EXTENSIONS
                                     else settings["assume_up_axis"])),
        "proxy_max_vertices": settings["proxy_max_vertices"],
        "collision_source": str(cand.collision_source) if cand.collision_source else None,
        "facts_face_budget": settings["facts_face_budget"],
        "size_hint": size_hint(cand),
    }


def size_hint(cand: Candidate) -> dict[str, Any]:
    """What the size decision knows of a candidate (:func:`mixcount.catalog.typical_sizes.sized`): its name
    and category, and a size stated in its metadata.json (``size``) or by ``catalog ingest --size-of``."""
    stated = cand.metadata.get("size")
    return {"name": cand.name, "category": cand.category, "stated": stated,
            "stated_by": str(cand.metadata.get("size_stated_by") or "size in the object's metadata.json")}


def run_analysis(kwargs: dict[str, Any]) -> Facts:
    """Process-pool task: (facts, None) or (None, reason). Never raises for a bad model."""
    from mixcount.catalog.mesh import analyse_model

    try:
        return analyse_model(**kwargs), None
    except IngestError as exc:
        return None, exc.reason
    except MemoryError:
        return None, "out of memory while analysing the mesh"
    except Exception as exc:  # a library bug on a weird file must not stop the batch
        return None, f"mesh analysis failed: {type(exc).__name__}: {str(exc)[:200]}"


def preload_analysis_modules() -> None:
    """Import what :func:`run_analysis` imports (trimesh, pymeshlab, the proxy builder) in this process,
    before the pool forks its workers: each forked worker then starts with them loaded. Left to the
    workers, every worker of every ingest imported them itself (trimesh ~0.6 s, pymeshlab ~0.1 s of CPU
    each): 37 CPU-seconds of the test suite's 26 `catalog ingest` runs (py-spy, docs/testing.md). Where
    processes are spawned instead of forked (not Linux's default) this only costs the parent's import."""
    import pymeshlab  # noqa: F401
    import scipy.spatial  # noqa: F401
    import trimesh  # noqa: F401

    import mixcount.catalog.mesh  # noqa: F401
    import mixcount.catalog.proxies  # noqa: F401


def analyse_all(jobs: list[tuple[Job, dict[str, Any]]], n_workers: int,
                finish: Callable[[Job, dict[str, Any] | None, str | None], None]) -> None:
    """Analyse each ``(job, kwargs)`` (process pool when > 1 worker and > 1 job) and call
    ``finish(job, facts, error)`` for each, in this process and in the order of ``jobs``.

    In order, not as each finishes: the caller stores each result as a new catalog row, so the row ids (which
    the compositor draws by) are the same whichever worker finishes first; the same library ingested twice is
    the same catalog. The workers still run ahead; only the storing waits for the earliest job.

    Under ``--executor ray`` (:func:`mixcount.catalog.step_executor.ray_tasks`) each analysis is a Ray task on the
    cluster, stored here in the same order; a task that died on every try is the object's run failure."""
    from mixcount.catalog.step_executor import TaskFailed, ray_tasks, run_and_collect

    cluster = ray_tasks()
    if cluster is not None:
        for (job, _kw), got in zip(jobs, cluster.map(run_analysis, [(kw,) for _job, kw in jobs])):
            if isinstance(got, TaskFailed):
                finish(job, None, f"mesh analysis crashed on the Ray cluster: {got.error}")
            else:
                finish(job, *got)
        return
    if n_workers <= 1 or len(jobs) == 1:
        for job, kwargs in jobs:
            facts, error = run_analysis(kwargs)
            finish(job, facts, error)
        return

    preload_analysis_modules()
    pool = ProcessPoolExecutor(max_workers=min(n_workers, len(jobs)), initializer=forked_worker_start)
    try:
        futures: list[tuple[Future, Job, dict[str, Any]]] = [
            (pool.submit(run_and_collect, run_analysis, kw), job, kw) for job, kw in jobs]
        for fut, job, kwargs in futures:
            try:
                facts, error = fut.result()
            except BrokenProcessPool:
                facts, error = _solo(kwargs)
            finish(job, facts, error)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _solo(kwargs: dict[str, Any]) -> Facts:
    """A worker died (segfault, OOM kill) and took the pool with it: analyse this model alone in a fresh
    process, so the one that crashes is identified and recorded as broken and the others still get ingested."""
    with ProcessPoolExecutor(max_workers=1, initializer=forked_worker_start) as solo:
        try:
            return solo.submit(run_analysis, kwargs).result()
        except BrokenProcessPool:
            return None, "mesh analysis crashed its worker process"
