"""The one way into a compose run, shared by ``mixcount compose`` and :func:`mixcount.api.compose`.

Why it exists: the CLI and the API used to take different ways down (the API skipped the count-target
and split checks the CLI made, and each loaded the object pool its own way). Both now build one
:class:`ComposeJob` from the run's :class:`~mixcount.config.Config` and hand it the catalog:

    job = ComposeJob.checked(config, n=n, out_dir=out)  # scene.count_target parsed once: a bad one stops here
    job.plan(catalog)   # --dry-run / --stage-only: the SceneSpecs the run would draw and what it will say
    job.run(catalog)    # inputs loaded, split checked, executor made, compose_scenes, executor closed

The job holds the Config itself (each setting typed once, in :mod:`mixcount.config`); below it
:func:`mixcount.run.compose.compose_scenes` turns the sections into the worker's request types once per
run. Nothing here prints: the CLI prints what :class:`ScenePlan` and the summary say.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from mixcount.config import Config
from mixcount.progress import ProgressReporter
from mixcount.run.compose import ComposeSummary, compose_scenes, count_target_of, require_split


@dataclass(frozen=True)
class ComposeInputs:
    """What a run draws from, loaded from the catalog once: the active objects (with their splits,
    captions and renders), the ingested environment maps and floor materials."""

    pool: list[Any]
    environments: list[Any]
    materials: list[Any]
    notes: list[str]  # what the run says at its start about objects of its split left out of the pool


@dataclass(frozen=True)
class ScenePlan:
    """A dry run's answer: the SceneSpecs the run would draw, and the notes it will say at its start
    (objects never captioned or rendered, seeds passed over, what it draws)."""

    specs: list[Any]
    notes: list[str] = field(default_factory=list)


def load_inputs(catalog: Any, config: Config) -> ComposeInputs:
    """The pool, environments and materials of ``catalog``; a CompositionError, before anything is
    written, when no active object is in ``compose.split`` (:func:`require_split`)."""
    from mixcount.catalog.pool_loader import damaged_texture_note, load_environments, load_materials, load_pool

    with catalog.session() as session:
        pool, environments, materials = (load_pool(session, palette=config.palette), load_environments(session),
                                         load_materials(session))
        require_split(pool, config.compose.split)  # an empty split stops here, before the note is looked up
        damaged = damaged_texture_note(session, config.compose.split)
    return ComposeInputs(pool, environments, materials, [damaged] if damaged else [])


@dataclass(frozen=True)
class ComposeJob:
    """One compose request, checked: ``n`` scenes of ``config.compose.split`` into ``out_dir``, with
    ``config.scene.count_target`` parsed once (:func:`~mixcount.run.compose.count_target_of`) and handed
    down to the run."""

    config: Config
    n: int
    out_dir: Path
    count_target: Any  # mixcount.counts.targets.CountDistribution

    @classmethod
    def checked(cls, config: Config, *, n: int, out_dir: Path) -> "ComposeJob":
        """The job, or the one-line error of a bad count target before anything is opened or written."""
        return cls(config=config, n=n, out_dir=Path(out_dir), count_target=count_target_of(config))

    def plan(self, catalog: Any) -> ScenePlan:
        """SceneSpecs of the ``n`` scenes a run of ``compose.split`` would draw into ``out_dir``: the seeds from
        ``compose.seed`` that the run draws (:func:`mixcount.run.seed_plan.planned_seeds`: finished and
        thrown-away scenes already in ``out_dir`` are passed over, as the run passes them; a seed that cannot
        be sampled is replaced by the next, as in the run), with what the run will say at its start."""
        from mixcount.run.object_pixels import plan_warning, planned_sizes
        from mixcount.run.readiness import missing_steps
        from mixcount.run.seed_plan import describe_passed, dry_plan
        from mixcount.scene.sampler import container_warning, sample_scene, size_warning

        config, n, out_dir = self.config, self.n, self.out_dir
        split, base = config.compose.split, config.compose.seed
        inputs = load_inputs(catalog, config)
        pool, envs, mats = inputs.pool, inputs.environments, inputs.materials
        lines = [w for w in [container_warning(pool, split, config.scene), size_warning(pool, split, config.scene)]
                 if w] + missing_steps(pool, split) + inputs.notes
        plan = dry_plan(out_dir, split, base, n,
                        lambda seed: sample_scene(seed, split, config, pool, environments=envs, materials=mats),
                        int(n * config.compose.max_attempts_factor) + 4)
        lines += [f"seed {seed} cannot be sampled ({err}): the run records it as failed and draws the next seed"
                  for seed, err in plan.unsampled]
        lines += describe_passed(plan.passed)
        specs = plan.specs
        if specs:  # how large the counted objects will be drawn (the run warns when under the floor)
            sizes = planned_sizes(specs, config.compose.min_object_px)
            lines.append(plan_warning(sizes) or sizes.line())
            lines.append(f"the run draws {', '.join(s.scene_id for s in specs[:8])}"
                         + (f" and {len(specs) - 8} more" if len(specs) > 8 else "")
                         + "; a scene that comes out empty at render is replaced by the next seed")
        elif plan.kept >= n:
            lines.append(f"nothing to draw: {plan.kept} finished scene(s) of split {split!r} in {out_dir} already "
                         f"make --n {n}")
        return ScenePlan(specs=list(specs), notes=lines)

    def run(self, catalog: Any, *, executor_kind: str = "local", workers: Optional[int] = None,
            address: Optional[str] = None, progress: ProgressReporter | bool | None = None,
            mixed_settings: bool = False) -> ComposeSummary:
        """Render until ``n`` scenes are complete in ``out_dir`` and merge them (:func:`compose_scenes`):
        the inputs loaded and the split checked before OUT is made (a failed start leaves nothing behind),
        a Ray executor made for ``executor_kind`` "ray" or an ``address`` (``workers``: its slots, None:
        the cluster's), else compose_scenes' own local pool of ``compose.workers``."""
        inputs = load_inputs(catalog, self.config)
        out_dir = self.out_dir.resolve()
        executor = None
        if executor_kind != "local" or address:
            from mixcount.run.factory import make_executor

            executor = make_executor(executor_kind, workers, address, config=self.config.compose,
                                     log_dir=out_dir / "logs")
        try:
            return compose_scenes(pool=inputs.pool, config=self.config, out_dir=out_dir,
                                  assets_dir=Path(catalog.usd_assets_dir).resolve(), n=self.n,
                                  environments=tuple(inputs.environments), materials=tuple(inputs.materials),
                                  executor=executor, progress=progress, mixed_settings=mixed_settings,
                                  catalog=catalog.url, count_target=self.count_target, notes=inputs.notes)
        finally:
            if executor is not None:
                executor.close()
