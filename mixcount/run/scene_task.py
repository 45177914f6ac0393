"""One unit of compose work, runnable by any executor: spec -> scene.usda -> worker -> finished folder.

:class:`SceneTask` is plain picklable data (a Ray executor ships it to another machine);
:func:`run_scene_task` needs only a :class:`~mixcount.worker.client.Worker` and never raises:
every failure becomes a :class:`SceneOutcome` with status "failed", so the batch goes on.
"""

from __future__ import annotations

import json
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Protocol

from mixcount.errors import RenderError
from mixcount.scene.spec import SceneSpec
from mixcount.worker.client import Worker
from mixcount.worker.contract import STATUS_EMPTY, STATUS_OK, MoreViews, SceneOutputs, SceneRequest, SceneResult

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
    outputs: SceneOutputs  # passes besides rgb, their formats, the mesh cache (SceneOutputs.from_config)
    oracle: bool = False  # also run the one-render-per-object reference (tests, benchmarks)
    captions: dict[int, dict[str, str]] = field(default_factory=dict)  # distractor captions by object id
    external_exemplars: dict[int, str] = field(default_factory=dict)  # object id -> render copy, relative to OUT
    keep_failed: bool = False
    more_views: Optional[MoreViews] = None  # compose --views: new cameras rendered in the same worker request
    device: Optional[str] = None  # compose.device as the run resolved it ("cpu" / "gpu"; None: the CPU)


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
    exit_code: Optional[int] = None  # a dead worker's exit (negative: the signal), mixcount.worker.client.WorkerDied
    log: Optional[str] = None  # that worker's kept log
    reason: Optional[dict[str, Any]] = None  # an empty / rejected scene: the rule and its figures (rejections.py)
    device: Optional[dict[str, Any]] = None  # what Cycles rendered on (DevicesResult.to_dict())

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class StagedScene:
    """A task's stage written ahead into its temporary folder (:func:`stage_scene`), with its request."""

    tmp: Path
    request: SceneRequest
    stage_s: float


def _request(task: SceneTask, tmp: Path) -> SceneRequest:
    return SceneRequest.for_outputs(task.outputs, stage=str(tmp / "scene.usda"), out_dir=str(tmp),
                                    threads=task.threads, oracle=task.oracle, more_views=task.more_views,
                                    device=task.device)


def _views_record(task: SceneTask, result: SceneResult) -> Optional[dict[str, Any]]:
    """metadata.json's ``more_views`` for ``compose --views`` (as ``mixcount render`` records ``rerender``);
    None without new views (nothing added)."""
    if task.more_views is None:
        return None
    own = next((d["own"] for d in result.diagnostics if d.get("kind") == "more_views"), len(result.views))
    return {"more_views": {"rule": task.more_views.rule, "views": len(result.views), "own_views": int(own),
                           "plan": task.more_views.plan.to_dict()}}


def _device_record(result: SceneResult) -> Optional[dict[str, Any]]:
    """What Cycles rendered the scene on (the worker's ``device`` diagnostic): used, backend, devices."""
    found = next((d for d in result.diagnostics if d.get("kind") == "device"), None)
    return None if found is None else {k: v for k, v in found.items() if k not in ("kind", "found", "error")}


def stage_scene(task: SceneTask) -> Optional[StagedScene]:
    """Write ``task``'s stage into a fresh temporary folder now (to settle it ahead, see
    :class:`~mixcount.worker.settle_ahead.SettleAheadWorker`); None when the scene is already complete or the
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
        write_stage(task.spec, out, assets_dir=Path(task.assets_dir), scene_dir=tmp)
    except Exception:  # noqa: BLE001 - run_scene_task writes it again and reports what fails
        shutil.rmtree(tmp, ignore_errors=True)
        return None
    return StagedScene(tmp, _request(task, tmp), round(time.perf_counter() - t, 4))


def render_fault_of(tmp: Path, result: SceneResult) -> Optional[str]:
    """Why the RGB image of one of the scene's cameras is no render of its inputs (black, or Blender's
    missing-image magenta: :func:`mixcount.catalog.media_check.render_fault`), naming the file; None when
    every one is a render."""
    from mixcount.catalog.media_check import render_fault

    for suffix in [v.suffix for v in result.views] or [""]:
        rgb = tmp / f"rgb{suffix}.png"
        if rgb.is_file():
            fault = render_fault(rgb)
            if fault:
                return f"{rgb.name}: {fault}"
    return None


class SceneRunner(Protocol):
    """What runs one task on one worker (:func:`run_scene_task`, or a test's own): with settle-ahead on, the
    executor passes the stage it wrote ahead as ``staged``."""

    def __call__(self, task: SceneTask, worker: Worker, staged: Optional[StagedScene] = None) -> SceneOutcome: ...


def run_scene_task(task: SceneTask, worker: Worker, staged: Optional[StagedScene] = None) -> SceneOutcome:
    """Write the stage into a temporary folder (unless ``staged`` did), render it with ``worker``,
    finalise, rename into place."""
    from mixcount.dataset.manifest import record_scene_files
    from mixcount.dataset.scene_writer import (
        REJECTED_DIR,
        finalize_scene,
        is_complete,
        move_into_place,
        tmp_dir_for,
        write_metadata,
    )
    from mixcount.run.rejections import object_lines, rejection_reason
    from mixcount.usd.dependencies import require_files
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
            write_stage(spec, out, assets_dir=Path(task.assets_dir), scene_dir=tmp)
            timings["stage"] = round(time.perf_counter() - t, 4)
            request = _request(task, tmp)
        else:
            timings["stage"] = staged.stage_s
            request = staged.request
        require_files(Path(request.stage), f"scene {spec.scene_id} cannot be rendered")  # never magenta (issue 60)
        t = time.perf_counter()
        result = worker.run_scene_job(request, timeout=task.timeout_s)
        timings["worker"] = round(time.perf_counter() - t, 4)
        status = result.status
        if status != STATUS_OK:  # thrown away: the record says which rule and its figures (rejections.py)
            reason = rejection_reason(result)
            rej = out / "scenes" / REJECTED_DIR
            rej.mkdir(parents=True, exist_ok=True)
            (rej / f"{spec.scene_id}.json").write_text(json.dumps(
                {"scene_id": spec.scene_id, "seed": spec.seed, "status": status, **reason,
                 "visibility_threshold": result.visibility_threshold, "objects": object_lines(result),
                 "diagnostics": list(result.diagnostics)}, indent=1))
            return SceneOutcome(spec.scene_id, spec.seed, EMPTY if status == STATUS_EMPTY else REJECTED,
                                time.perf_counter() - t0, error=f"scene {status}: {reason['why']}", timings=timings,
                                reason=reason)
        fault = render_fault_of(tmp, result)
        if fault:  # black / magenta where the inputs are not: a failed scene, never a written one (issue 68)
            raise RenderError(f"scene {spec.scene_id}: {fault}")
        t = time.perf_counter()
        timings["total"] = 0.0
        device = _device_record(result)
        extra = {**(_views_record(task, result) or {}), **({"render_device": device} if device else {})}
        meta = finalize_scene(tmp, spec, result, captions=task.captions, timings=timings,
                              external_exemplars=task.external_exemplars, passes=task.outputs.passes,
                              extra=extra or None)
        timings["annotate"] = round(time.perf_counter() - t, 4)
        timings["total"] = round(time.perf_counter() - t0, 4)
        meta["timings"].update(annotate=timings["annotate"], total=timings["total"])
        write_metadata(tmp, meta)
        record_scene_files(tmp)  # size + hash of every file the folder holds (mixcount verify)
        move_into_place(tmp, final)
        return SceneOutcome(spec.scene_id, spec.seed, WRITTEN, time.perf_counter() - t0,
                            n_counted=int(meta["n_counted"]), path=str(final), timings=timings, device=device)
    except Exception as exc:  # noqa: BLE001 - the batch goes on; the error is reported
        return SceneOutcome(spec.scene_id, spec.seed, FAILED, time.perf_counter() - t0,
                            error=f"{type(exc).__name__}: {exc}"[:4000], timings=timings,
                            exit_code=getattr(exc, "exit_code", None), log=getattr(exc, "log", None))
    finally:
        if tmp.exists() and not task.keep_failed:
            shutil.rmtree(tmp, ignore_errors=True)
