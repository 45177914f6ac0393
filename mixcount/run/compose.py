"""``mixcount compose`` rendering run: seeds -> SceneTasks -> executor -> finished scenes -> dataset.

Seeds are drawn in order from the base seed (scene_id ``scene_<seed:06d>``). A complete scene folder
counts as written and is skipped; a seed whose scene came out empty (no counted object visible enough)
or failed the final visibility re-check is recorded under ``OUT/scenes/.rejected/`` and the next seed is
drawn (the paper's "regenerate"); errors and timeouts are reported and retried by a rerun. ``n`` counts
written scenes. The canonical render of every object a scene uses is copied to ``OUT/exemplars/external/``
(:mod:`mixcount.dataset.external_exemplars`) before its task runs. At the end the COCO files are merged
and dataset.json / preview.png / ATTRIBUTION rewritten from every complete scene in OUT, in one streaming
pass (:mod:`mixcount.dataset.merge`), when the call wrote a scene or the dataset files are missing, and
``compose.merge`` (or ``merge``) is on; ``mixcount merge`` does it on its own.

Faults (docs/faults.md): a finished scene whose files no longer match their record
(:mod:`mixcount.dataset.manifest`) is set aside under ``OUT/scenes/.damaged/`` and rendered again. A
fault no seed can fix - the output folder full, read-only or not writable, a scene's input file
missing or unreadable (:mod:`mixcount.run.faults`) - stops the run: no new seed is drawn, the scenes in
flight finish (or fail and leave nothing), no merge is attempted, and :class:`StorageError` /
:class:`AssetError` carries one line naming the path and the cause.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from mixcount.config import Config
from mixcount.errors import AssetError, CompositionError, MixcountError, StoppedByUser, StorageError, os_error_line
from mixcount.progress import ProgressReporter, as_reporter
from mixcount.run.local import Executor
from mixcount.run.object_pixels import (
    IMAGES,
    PLAN,
    PixelSizes,
    PixelTally,
    measured_object_px,
    plan_warning,
    planned_object_px,
    planned_sizes,
)
from mixcount.run.scene_task import EMPTY, FAILED, REJECTED, SKIPPED, WRITTEN, SceneOutcome, SceneTask
from mixcount.scene_config import RULE_ALL_CAMERAS
from mixcount.worker.contract import MoreViews, SceneOutputs


@dataclass
class ComposeSummary:
    requested: int
    written: int = 0  # finished scenes of the split counted towards ``requested``: new ones + ``skipped``
    skipped: int = 0  # of ``written``: finished before this run (already there)
    settings_id: int = 0  # the variant of OUT/settings.json this run's scenes hold
    empty: int = 0
    rejected: int = 0
    failed: int = 0
    seconds: float = 0.0
    failures: list[dict[str, Any]] = field(default_factory=list)
    outcomes: list[dict[str, Any]] = field(default_factory=list)
    outputs: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    damaged: list[dict[str, Any]] = field(default_factory=list)  # finished scenes set aside and redone
    stopped: Optional[str] = None  # the fault that stopped the run (no new seed drawn after it)
    device: Optional[str] = None  # what the scenes rendered on: "cpu" or "gpu" (compose.device resolved)
    # pixels per counted object (mixcount.run.object_pixels): "plan" (the scenes this run drew) and "images"
    # (the visible counted objects of the scenes it wrote), each median / smallest against the floor
    object_px: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def render_threads(threads: int, workers: int) -> int:
    """Cycles threads per worker: ``compose.render_threads`` (``threads``), or CPU count / workers when it is 0."""
    return threads or max(1, (os.cpu_count() or 1) // max(1, workers))


def compose_scenes(
    *, pool: list[Any], config: Config, out_dir: Path, assets_dir: Path, n: int, executor: Optional[Executor] = None,
    environments: tuple = (), materials: tuple = (), progress: ProgressReporter | bool | None = None, oracle: bool = False,
    on_outcome: Optional[Callable[[SceneOutcome], None]] = None, passes: Optional[str | list[str]] = None,
    merge: Optional[bool] = None, catalog: Optional[str] = None, mixed_settings: bool = False,
    count_target: Any = None, notes: Sequence[str] = (),
) -> ComposeSummary:
    """Render until ``n`` scenes of ``compose.split`` are complete in ``out_dir`` (see module docstring).

    Seeds start at ``compose.seed``; without an ``executor`` a local pool of ``compose.workers`` runs.
    Steps: check the output folder and the inputs, draw and run scenes (:class:`_ComposeRun`), stop with
    one error after a fault no seed can fix, merge.

    ``catalog`` (the catalog's URL) and the run's dataset settings are checked against those of the scenes
    already in ``out_dir`` (:mod:`mixcount.dataset.settings`): other settings are a CompositionError unless
    ``mixed_settings``, which records them as another variant. ``count_target``: ``scene.count_target``
    as :class:`~mixcount.run.compose_entry.ComposeJob` parsed it (None: parsed here when views need it).
    ``notes``: lines about the inputs said at the start with the run's own warnings (objects left out)."""
    from mixcount.dataset.settings import check_settings, dataset_settings
    from mixcount.scene.environment_sampling import environments_to_draw
    from mixcount.scene.sampler import container_warning, size_warning

    comp = config.compose
    out_dir = Path(out_dir)
    require_split(pool, comp.split)  # before anything is made on disk
    more_views = more_views_of(config, count_target)  # a refused pair stops here, before OUT is made
    # the executor's own device (Ray: from its cluster) or compose.device resolved here with one bpy probe
    # (none for cpu): --device gpu without one stops here, before OUT is made
    from mixcount.run.devices import executor_device, resolve_device

    device = executor_device(executor) or resolve_device(comp.device)
    _prepare_output(out_dir)
    # bpy's bundled HDRIs when none were ingested (scene.default_environment): found once, so a bpy
    # without them stops the run here with one clear error instead of failing every scene's sampling
    environments = tuple(environments_to_draw(config.scene, environments))
    outputs = SceneOutputs.from_config(comp, passes)
    settings = dataset_settings(config, passes=list(outputs.passes), catalog=catalog)
    if more_views is not None:  # the views a scene holds are part of what the dataset is
        settings.update({f"rerender.{k}": v for k, v in more_views.to_dict()["plan"].items() if k != "camera_rule"})
        settings["rerender.annotation_rule"] = more_views.rule
    settings_id = check_settings(out_dir, settings, config.hash, allow_mixed=mixed_settings)
    summary = ComposeSummary(requested=n, settings_id=settings_id)
    t0 = time.perf_counter()
    own_executor = executor is None
    if own_executor:
        from mixcount.run.local import LocalExecutor

        executor = LocalExecutor(comp.workers, log_dir=out_dir / "logs", recycle_after=comp.recycle_after,
                                 settle_ahead=comp.settle_ahead,
                                 cpu_threads=render_threads(comp.render_threads, comp.workers))
    bar = as_reporter(progress)
    run = _ComposeRun(config=config, pool=pool, out_dir=out_dir, assets_dir=Path(assets_dir), n=n,
                      environments=environments, materials=materials, oracle=oracle, outputs=outputs,
                      summary=summary, bar=bar, more_views=more_views, device=device.device)
    if device.note:  # once per run
        summary.warnings.append(device.note)
        bar.note(device.note)
    summary.device = device.device
    from mixcount.run.readiness import missing_steps

    small = plan_warning(first_scenes_px(config, pool, environments, materials, n))
    for warning in [container_warning(pool, comp.split, config.scene), size_warning(pool, comp.split, config.scene),
                    *missing_steps(pool, comp.split), small, *notes]:
        if warning:  # once per run, not once per scene
            summary.warnings.append(warning)
            bar.note(warning)
    bar.start("compose", n)
    stopped = False
    try:
        run.drive(executor, on_outcome)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: finished scenes are complete on disk, a rerun passes over them
        stopped = True
    finally:
        bar.stop()
        if own_executor or stopped:  # a stopped run's executor is done (close is idempotent): closed here,
            executor.close()  # so its scenes in flight are finished or ended before they are counted
    if stopped:  # counted after the executor closed: a scene it completed while stopping is kept too
        kept = summary.written + run.finished_while_stopping()
        raise StoppedByUser(f"stopped by the user; {kept} scene{'' if kept == 1 else 's'} "
                            "finished and kept; rerun the same command to go on")
    summary.seconds = round(time.perf_counter() - t0, 3)
    summary.object_px = run.object_px()
    run.raise_if_stopped()
    if summary.written < n:
        bar.note(f"only {summary.written} of {n} scenes written after {run.attempts} attempts")
    if (comp.merge if merge is None else merge) and merge_is_stale(out_dir):
        _merge(out_dir, config, summary, bar)
    return summary


PLAN_PX_SCENES = 16  # scenes sampled at the start of a run for its pixels-per-object warning


def first_scenes_px(config: Config, pool: list[Any], environments: tuple, materials: tuple, n: int) -> PixelSizes:
    """Pixels per counted object of the first scenes the run would draw (``compose.seed`` on, at most
    :data:`PLAN_PX_SCENES`; a seed that cannot be sampled is left out): sampling is cheap, nothing renders."""
    from mixcount.scene.sampler import sample_scene

    specs = []
    for seed in range(config.compose.seed, config.compose.seed + min(n, PLAN_PX_SCENES)):
        try:
            specs.append(sample_scene(seed, config.compose.split, config, pool, environments=environments,
                                      materials=materials))
        except Exception:  # noqa: BLE001 - the run records such a seed as failed; the estimate goes without it
            continue
    return planned_sizes(specs, config.compose.min_object_px)


def require_split(pool: list[Any], split: str) -> None:
    """A CompositionError, before anything is written, when no active object of the pool is in ``split``:
    it says how many objects each split holds, so a small library's empty val split is plain."""
    if any(getattr(o, "split", None) == split for o in pool):
        return
    from mixcount.config import SPLIT_NAMES

    held = {s: sum(1 for o in pool if getattr(o, "split", None) == s) for s in SPLIT_NAMES}
    held = {s: k for s, k in held.items() if k or s in ("train", "val", "test", split)}
    unsplit = sum(1 for o in pool if getattr(o, "split", None) is None)
    raise CompositionError(
        f"no active objects in split {split!r} (active objects per split: "
        + ", ".join(f"{s} {n}" for s, n in held.items()) + (f", no split {unsplit}" if unsplit else "")
        + "): " + ("run `mixcount catalog split` (after ingest and caption); nothing was written" if not pool or unsplit
                   else "compose another split, or add objects or change split.fractions and run `mixcount catalog "
                        "split` again; nothing was written"))


def count_target_of(config: Config) -> Any:
    """``scene.count_target`` parsed (:class:`~mixcount.counts.targets.CountDistribution`): the one place
    a run reads it (a bad target is its error, before anything is written); the sampler keeps its own
    cached copy per scene."""
    from mixcount.counts.targets import parse_count_target

    return parse_count_target(config.scene.count_target)


def more_views_of(config: Config, count_target: Any = None) -> Optional[MoreViews]:
    """``compose --views K`` / ``--trajectory orbit``: the new cameras each scene gets in its own worker request
    (``[rerender]``'s views, rule and persistent data); None for none. Under the paper's all-cameras rule the
    new views can remove objects a count target (``scene.count_target``, or ``count_target`` already parsed)
    was met with: that pair is refused."""
    more = MoreViews.from_config(config.rerender, config.scene)
    if more is None or more.rule != RULE_ALL_CAMERAS:
        return more
    if not (count_target if count_target is not None else count_target_of(config)).is_paper:
        raise CompositionError("compose --views with a count target (--counts): the all_cameras rule would remove "
                               "objects the target counted in the new views; use --rule per_view (nothing is "
                               "removed), or compose then `mixcount render --views`; nothing was written")
    return more


def _prepare_output(out_dir: Path) -> None:
    """``OUT/scenes`` made, both folders writable with space to spare, stale temporary scenes removed."""
    from mixcount.dataset.scene_writer import clean_stale_tmp
    from mixcount.run.faults import check_output

    try:
        (out_dir / "scenes").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StorageError(f"cannot create the output folder: {os_error_line(exc)}") from None
    for folder in (out_dir / "scenes", out_dir):
        problem = check_output(folder)
        if problem:
            raise StorageError(f"{problem}; nothing was rendered")
    clean_stale_tmp(out_dir)


def _merge(out_dir: Path, config: Config, summary: ComposeSummary, bar: ProgressReporter) -> None:
    """The merged dataset files from every finished scene (a full disk: one StorageError, scenes kept)."""
    from mixcount.dataset.merge import finalize_dataset

    try:
        summary.outputs = finalize_dataset(
            out_dir, config=config.to_dict(), config_hash=config.hash,
            run={k: v for k, v in summary.to_dict().items() if k not in ("outcomes", "outputs")},
            preview_scenes=config.compose.preview_scenes,
        )
    except OSError as exc:
        raise StorageError(f"cannot merge the dataset: {os_error_line(exc)}; the {summary.written} finished "
                           "scene(s) are kept: free space, then run `mixcount merge` on the folder") from None
    for line in summary.outputs.get("damaged", []):
        bar.note(f"left out of the merge: {line}")


@dataclass
class _ComposeRun:
    """One compose run's state: the next seed, the scenes in flight and the fault that stopped it."""

    config: Config
    pool: list[Any]
    out_dir: Path
    assets_dir: Path
    n: int
    environments: tuple
    materials: tuple
    oracle: bool
    outputs: SceneOutputs  # SceneTask's passes, formats and mesh cache
    summary: ComposeSummary
    bar: ProgressReporter
    more_views: Optional[MoreViews]  # compose --views: each task's new cameras (None: the scene's own only)
    device: str  # "cpu" | "gpu": compose.device as resolved for this run (mixcount.run.devices)
    attempts: int = 0
    pending: set[str] = field(default_factory=set)  # scene ids submitted and not yet come back
    fatal: Optional[MixcountError] = None  # a fault no seed can fix: draw no new seed after it
    largest_scene: int = 0  # bytes of the largest scene written by this run (how much free space one needs)
    external: dict[int, str] = field(default_factory=dict)  # object id -> its render's copy under OUT/exemplars
    planned_px: PixelTally = field(default_factory=PixelTally.empty)  # counted objects' box sides, planned
    written_px: PixelTally = field(default_factory=PixelTally.empty)  # and in the images this run wrote

    def __post_init__(self) -> None:
        comp = self.config.compose
        self.split = comp.split
        self.next_seed = comp.seed
        self.max_attempts = int(math.ceil(self.n * comp.max_attempts_factor)) + 4
        self.threads = render_threads(comp.render_threads, comp.workers)
        self.captions = {int(o.object_id): o.captions.to_dict() for o in self.pool}
        self.renders = {int(o.object_id): o.render_path for o in self.pool}

    def stop(self, error: MixcountError) -> None:
        if self.fatal is None:
            self.fatal = error
            self.summary.stopped = str(error)

    def raise_if_stopped(self) -> None:
        """After a fault: one error that says what stopped the run, what was kept and what to do."""
        fatal = self.fatal
        if fatal is None:
            return
        advice = ("restore the file or re-ingest its library" if isinstance(fatal, AssetError)
                  else "free space or make the folder writable")
        raise type(fatal)(f"{fatal}; compose stopped with {self.summary.written} of {self.n} scene(s) finished "
                          f"and kept, no new seed drawn: {advice}, then run the same command again")

    def finished_scene_counts(self, sdir: Path, sid: str) -> bool:
        """Whether the seed is passed over (a sound finished scene, counted when of this split; a scene of
        another split; a seed an earlier run threw away), by :func:`mixcount.run.seed_plan.seed_state`, the
        rule the dry run shows; a damaged scene of this split (or of no readable split) is set aside first
        and then rendered again."""
        from mixcount.dataset.manifest import check_scene, set_aside
        from mixcount.run.seed_plan import DAMAGED, KEPT, NEW, OTHER_SPLIT, scene_split, seed_state

        state = seed_state(self.out_dir, sid, self.split)
        if state == NEW:
            return False
        if state == DAMAGED:
            check = check_scene(sdir, deep=False)
            try:
                moved = set_aside(sdir, check)
            except OSError as exc:
                self.stop(StorageError(f"cannot set damaged scene {sid} aside: {os_error_line(exc)}"))
                return True
            self.summary.damaged.append({"scene_id": sid, "problems": check.describe(),
                                         "moved_to": None if moved is None else str(moved)})
            self.bar.note(f"scene {sid} is damaged ({check.describe()}): set aside as "
                          f"{moved if moved is not None else 'by another run'}; rendering it again")
            return False
        if state == OTHER_SPLIT and (sdir / "metadata.json").exists():
            check = check_scene(sdir, deep=False)
            if check.damaged:
                meta_split = scene_split(sdir)
                self.bar.note(f"scene {sid} of split {meta_split} is damaged ({check.describe()}): "
                              f"left for a compose of split {meta_split} to repair")
        if state == KEPT:
            self.summary.skipped += 1
            self.summary.written += 1
        return True

    def next_task(self) -> Optional[SceneTask]:
        """The next seed's task: finished and rejected seeds are passed over, a seed that cannot be sampled
        is a failed scene, a missing asset or an unwritable exemplar copy stops the run (None)."""
        from mixcount.scene.sampler import scene_id_for

        summary = self.summary
        while self.attempts < self.max_attempts and self.fatal is None:
            s = self.next_seed
            self.next_seed += 1
            sid = scene_id_for(s)
            if self.finished_scene_counts(self.out_dir / "scenes" / sid, sid):
                if summary.written >= self.n or self.fatal is not None:
                    return None
                continue
            self.attempts += 1
            task = self._task(s, sid)
            if task is not None or self.fatal is not None:
                return task
        return None

    def _task(self, seed: int, sid: str) -> Optional[SceneTask]:
        from mixcount.dataset.external_exemplars import copy_external_exemplars
        from mixcount.run.faults import missing_inputs
        from mixcount.scene.sampler import sample_scene

        try:
            spec = sample_scene(seed, self.split, self.config, self.pool, environments=self.environments,
                                materials=self.materials)
        except Exception as exc:  # noqa: BLE001 - a seed that cannot be sampled is a failed scene
            self.record_failure(SceneOutcome(sid, seed, FAILED, 0.0, error=f"sampling: {exc}"))
            return None
        problem = missing_inputs(spec, self.assets_dir)
        if problem:
            self.stop(AssetError(f"scene {sid} cannot be rendered: {problem}"))
            return None
        used = {c.object_id for c in spec.classes} | {d.object_id for d in spec.distractors}
        try:
            self.external.update(copy_external_exemplars(self.out_dir, self.renders, used - set(self.external)))
        except OSError as exc:
            self.stop(StorageError(f"cannot copy external exemplars: {os_error_line(exc)}"))
            return None
        distractors = {d.object_id for d in spec.distractors}
        self.planned_px.add(planned_object_px(spec))
        return SceneTask(spec=spec, out_dir=str(self.out_dir), assets_dir=str(self.assets_dir),
                         timeout_s=self.config.compose.scene_timeout_s, threads=self.threads, oracle=self.oracle,
                         captions={k: v for k, v in self.captions.items() if k in distractors},
                         external_exemplars={k: self.external[k] for k in sorted(used) if k in self.external},
                         outputs=self.outputs, more_views=self.more_views, device=self.device)

    def object_px(self) -> dict[str, Any]:
        """The summary's ``object_px``: the plan of the scenes this run drew and the images it wrote."""
        floor = self.config.compose.min_object_px
        return {"floor_px": floor, PLAN: self.planned_px.sizes(floor, PLAN).to_dict(),
                IMAGES: self.written_px.sizes(floor, IMAGES).to_dict()}

    def info(self) -> str:
        return f"failed {self.summary.failed}  regenerated {self.summary.empty + self.summary.rejected}"

    def drive(self, executor: Executor, on_outcome: Optional[Callable[[SceneOutcome], None]]) -> None:
        """Keep the executor's slots full until ``n`` scenes are written; after a fault drain, draw none."""
        summary, bar = self.summary, self.bar
        while summary.written < self.n or (self.fatal is not None and self.pending):
            while self.fatal is None and len(self.pending) < executor.slots and \
                    summary.written + len(self.pending) < self.n:
                task = self.next_task()
                if task is None:
                    break
                executor.submit(task)
                self.pending.add(task.spec.scene_id)  # one seed, one scene id: never two in flight
            bar.update(completed=summary.written, info=self.info())
            if not self.pending:
                break
            outcome = executor.next_outcome()
            self.pending.discard(outcome.scene_id)
            self.record(outcome)
            if on_outcome is not None:
                on_outcome(outcome)
            bar.update(completed=summary.written, info=self.info())

    def finished_while_stopping(self) -> int:
        """Scenes in flight when the run was stopped that are finished on disk now: a worker thread still
        inside a scene's writing, or a Ray actor asked to close after its scene, completes it while the
        executor closes (a SIGTERM reaches the driver only), so the "kept" count of a stop is read from the
        folders, not from the outcomes alone."""
        from mixcount.dataset.manifest import is_finished

        return sum(1 for sid in self.pending if is_finished(self.out_dir / "scenes" / sid))

    def record(self, outcome: SceneOutcome) -> None:
        """Count one outcome; a failure whose cause no seed can fix (a full disk, ...) stops the run."""
        from mixcount.dataset.manifest import recorded_size

        summary = self.summary
        summary.outcomes.append(outcome.to_dict())
        if outcome.status == WRITTEN:
            summary.written += 1
            self.largest_scene = max(self.largest_scene, recorded_size(Path(outcome.path or "")))
            if outcome.path:
                self.written_px.add(measured_object_px(Path(outcome.path)))
        elif outcome.status == SKIPPED:
            summary.written += 1
            summary.skipped += 1
        elif outcome.status == EMPTY:
            summary.empty += 1
        elif outcome.status == REJECTED:
            summary.rejected += 1
        else:
            self.record_failure(outcome)

    def record_failure(self, outcome: SceneOutcome) -> None:
        """A failed scene: counted, its line appended to ``OUT/logs/failures.jsonl`` (cause, exit signal,
        kept log and its last lines, seed) and noted with those last lines; a cause no seed can fix stops
        the run."""
        from mixcount.run.failures import append_failure, failure_record
        from mixcount.run.faults import classify_failure, failure_cause, scene_bytes_needed

        summary = self.summary
        summary.failed += 1
        need = scene_bytes_needed(self.config.compose.resolution, self.largest_scene)
        problem = classify_failure(outcome.error, out_dir=self.out_dir, assets_dir=self.assets_dir, need_bytes=need)
        cause = "storage" if problem else failure_cause(outcome.error, outcome.exit_code)
        rec = failure_record(outcome, split=self.split, cause=cause)
        summary.failures.append({"scene_id": outcome.scene_id, "seed": outcome.seed, "error": outcome.error,
                                 "cause": cause, "exit_code": outcome.exit_code, "log": outcome.log,
                                 "log_tail": rec["log_tail"], "reproduce": rec["reproduce"]})
        append_failure(self.out_dir, rec)
        if problem:
            self.stop(StorageError(problem))
        elif "AssetError: " in (outcome.error or "").split("\n", 1)[0]:  # a file it needs (here or in the worker)
            self.stop(AssetError((outcome.error or "").split("\n", 1)[0].split("AssetError: ", 1)[1]))
        elif self.fatal is None:
            tail = "".join(f"\n    {ln[:200]}" for ln in rec["log_tail"].splitlines())  # the log's last lines
            self.bar.note(f"scene {outcome.scene_id} (seed {outcome.seed}) failed [{cause}]: "
                          f"{(outcome.error or '').splitlines()[0][:300] if outcome.error else ''}{tail}")


def merge_is_stale(out_dir: Path) -> bool:
    """Whether a scene folder appeared since dataset.json was written (a folder renamed into ``scenes/``
    updates its modification time), or dataset.json is missing."""
    try:
        return (Path(out_dir) / "scenes").stat().st_mtime_ns > (Path(out_dir) / "dataset.json").stat().st_mtime_ns
    except OSError:
        return True

