"""One unit of compose work, runnable by any executor: spec -> scene.usda -> worker -> finished folder.

:class:`SceneTask` is plain picklable data (a Ray executor ships it to another machine);
:func:`run_scene_task` needs only a :class:`~mixcount.worker.client.BlenderWorker` and never raises:
every failure becomes a :class:`SceneOutcome` with status "failed", so the batch goes on.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from mixcount.config import ComposeConfig
from mixcount.scene.spec import SceneSpec
from mixcount.worker.contract import STATUS_EMPTY, STATUS_OK, SceneRequest

WRITTEN = "written"
SKIPPED = "skipped"  # already complete
EMPTY = "empty"  # no counted object survived: regenerate from the next seed
REJECTED = "rejected"  # the final visibility re-check failed
FAILED = "failed"  # error or timeout


@dataclass(frozen=True)
class SceneTask:
    spec: SceneSpec
    out_dir: str
    assets_dir: str
    timeout_s: float
    threads: int  # Cycles threads in the worker (run-time only; the scene's settings travel in the stage)
    passes: tuple[str, ...]  # besides rgb (compose.passes / --passes)
    depth_format: str  # compose.depth_format / normal_format (mixcount.annotate.passes formats)
    normal_format: str
    mesh_cache: str  # the worker's .blend cache of imported asset meshes (compose.mesh_cache)
    oracle: bool = False  # also run the one-render-per-object reference (tests, benchmarks)
    captions: dict[int, dict[str, str]] = field(default_factory=dict)  # distractor captions by object id
    external_exemplars: dict[int, str] = field(default_factory=dict)  # object id -> render copy, relative to OUT
    keep_failed: bool = False


def compose_outputs(compose: ComposeConfig) -> dict[str, Any]:
    """A SceneTask's output fields as ``[compose]`` sets them (passes, their formats, the mesh cache)."""
    return {"passes": tuple(compose.passes), "depth_format": compose.depth_format,
            "normal_format": compose.normal_format, "mesh_cache": compose.mesh_cache}


@dataclass
class SceneOutcome:
    scene_id: str
    seed: int
    status: str
    seconds: float
    error: Optional[str] = None
    n_counted: int = 0
    path: Optional[str] = None
    timings: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


# usd-core used by one thread at a time in this process (stages, asset conversion, settled.usda): the
# settle-ahead look-ahead writes the next scene's stage while the current scene is written or finalised,
# and two threads converting the same asset (Usd.Stage.CreateNew of one path) deadlock
_USD_WRITING = threading.Lock()


@dataclass
class StagedScene:
    """A task's stage written ahead into its temporary folder (:func:`stage_scene`), with its request."""

    tmp: Path
    request: SceneRequest
    stage_s: float


def _request(task: SceneTask, tmp: Path) -> SceneRequest:
    return SceneRequest(stage=str(tmp / "scene.usda"), out_dir=str(tmp), threads=task.threads,
                        oracle=task.oracle, passes=tuple(task.passes), depth_format=task.depth_format,
                        normal_format=task.normal_format, mesh_cache=task.mesh_cache, settled="")


def stage_scene(task: SceneTask) -> Optional[StagedScene]:
    """Write ``task``'s stage into a fresh temporary folder now (to settle it ahead, see
    :class:`~mixcount.worker.client.SettleAheadWorker`); None when the scene is already complete or the
    stage cannot be written (:func:`run_scene_task` then does it all and reports the error)."""
    from mixcount.dataset.scene_writer import is_complete, tmp_dir_for
    from mixcount.usd.stage import write_stage

    out = Path(task.out_dir)
    if is_complete(out / "scenes" / task.spec.scene_id):
        return None
    tmp = tmp_dir_for(out, task.spec.scene_id, uuid.uuid4().hex[:8])
    t = time.perf_counter()
    try:
        tmp.mkdir(parents=True)
        with _USD_WRITING:
            write_stage(task.spec, out, assets_dir=Path(task.assets_dir), scene_dir=tmp)
    except Exception:  # noqa: BLE001 - run_scene_task writes it again and reports what fails
        shutil.rmtree(tmp, ignore_errors=True)
        return None
    return StagedScene(tmp, _request(task, tmp), round(time.perf_counter() - t, 4))


def run_scene_task(task: SceneTask, worker: Any, staged: Optional[StagedScene] = None) -> SceneOutcome:
    """Write the stage into a temporary folder (unless ``staged`` did), render it with ``worker``,
    finalise, rename into place."""
    from mixcount.dataset.manifest import record_scene_files
    from mixcount.dataset.scene_writer import REJECTED_DIR, finalize_scene, is_complete, move_into_place, tmp_dir_for
    from mixcount.usd.stage import write_stage

    spec = task.spec
    t0 = time.perf_counter()
    out = Path(task.out_dir)
    final = out / "scenes" / spec.scene_id
    if staged is None and is_complete(final):
        return SceneOutcome(spec.scene_id, spec.seed, SKIPPED, 0.0, path=str(final))
    tmp = staged.tmp if staged is not None else tmp_dir_for(out, spec.scene_id, uuid.uuid4().hex[:8])
    timings: dict[str, float] = {}
    try:
        if staged is None:
            tmp.mkdir(parents=True)
            t = time.perf_counter()
            with _USD_WRITING:
                write_stage(spec, out, assets_dir=Path(task.assets_dir), scene_dir=tmp)
            timings["stage"] = round(time.perf_counter() - t, 4)
            request = _request(task, tmp)
        else:
            timings["stage"] = staged.stage_s
            request = staged.request
        t = time.perf_counter()
        result = worker.render_scene(request, timeout=task.timeout_s)
        timings["worker"] = round(time.perf_counter() - t, 4)
        status = result.status
        if status != STATUS_OK:
            rej = out / "scenes" / REJECTED_DIR
            rej.mkdir(parents=True, exist_ok=True)
            (rej / f"{spec.scene_id}.json").write_text(json.dumps(
                {"scene_id": spec.scene_id, "seed": spec.seed, "status": status,
                 "diagnostics": list(result.diagnostics)}, indent=1))
            return SceneOutcome(spec.scene_id, spec.seed, EMPTY if status == STATUS_EMPTY else REJECTED,
                                time.perf_counter() - t0, error=f"scene {status}", timings=timings)
        t = time.perf_counter()
        timings["total"] = 0.0
        with _USD_WRITING:
            meta = finalize_scene(tmp, spec, result, captions=task.captions, timings=timings,
                                  external_exemplars=task.external_exemplars, passes=task.passes)
        timings["annotate"] = round(time.perf_counter() - t, 4)
        timings["total"] = round(time.perf_counter() - t0, 4)
        meta["timings"].update(annotate=timings["annotate"], total=timings["total"])
        (tmp / "metadata.json").write_text(json.dumps(meta, indent=1))
        record_scene_files(tmp)  # size + hash of every file the folder holds (mixcount verify)
        move_into_place(tmp, final)
        return SceneOutcome(spec.scene_id, spec.seed, WRITTEN, time.perf_counter() - t0,
                            n_counted=int(meta["n_counted"]), path=str(final), timings=timings)
    except Exception as exc:  # noqa: BLE001 - the batch goes on; the error is reported
        return SceneOutcome(spec.scene_id, spec.seed, FAILED, time.perf_counter() - t0,
                            error=f"{type(exc).__name__}: {exc}"[:4000], timings=timings)
    finally:
        if tmp.exists() and not task.keep_failed:
            shutil.rmtree(tmp, ignore_errors=True)
