"""Which seeds a compose run draws, read from the output folder: one rule for the run and its dry run.

A run does not write ``scene_<base>`` .. ``scene_<base+n-1>``: it walks the seeds from ``compose.seed``
and passes over what ``OUT/scenes`` already holds (issue 56: a dry run listed scene_000000/1 while the
run wrote scene_000004/5, because seeds 0-3 had been thrown away as empty by an earlier run).
:func:`seed_state` is that rule for one seed, read-only:

* ``kept`` - a sound finished scene of the split: counted towards ``n``, not drawn again;
* ``other_split`` - a finished scene of another split, or a damaged one of another split: passed over;
* ``rejected`` - a marker under ``scenes/.rejected/`` (an earlier run found it empty or rejected): passed;
* ``damaged`` - a finished scene of this split whose files no longer match their record: the run sets it
  aside and draws the seed again;
* ``new`` - nothing there: drawn.

:func:`planned_seeds` walks the seeds as the run does until ``n`` are kept or drawn. What only the render
can tell - a scene that comes out empty or fails - makes the run draw the next seed after the plan's last.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

KEPT, OTHER_SPLIT, REJECTED_BEFORE, DAMAGED, NEW = "kept", "other_split", "rejected", "damaged", "new"
DRAWN = (NEW, DAMAGED)  # states whose seed the run samples and renders
COUNTED = (KEPT, NEW, DAMAGED)  # states that count towards n (a drawn seed, if its render succeeds)


@dataclass(frozen=True)
class SeedStep:
    """One seed of the walk and what the run does with it."""

    seed: int
    scene_id: str
    state: str


def scene_split(scene_dir: Path) -> Optional[str]:
    """The split recorded in a scene folder's metadata.json (None when unreadable)."""
    try:
        split = json.loads((scene_dir / "metadata.json").read_text()).get("split")
    except (OSError, ValueError, AttributeError):
        return None
    return split if isinstance(split, str) else None


def seed_state(out_dir: Path, scene_id: str, split: str) -> str:
    """What ``OUT/scenes/<scene_id>`` means for a run of ``split`` (module docstring); reads, never writes."""
    from mixcount.dataset.manifest import check_scene, is_finished
    from mixcount.dataset.scene_writer import REJECTED_DIR

    sdir = Path(out_dir) / "scenes" / scene_id
    if is_finished(sdir):
        meta_split = scene_split(sdir)
        if check_scene(sdir, deep=False).damaged:
            return DAMAGED if meta_split in (split, None) else OTHER_SPLIT
        return KEPT if meta_split == split else OTHER_SPLIT
    if (Path(out_dir) / "scenes" / REJECTED_DIR / f"{scene_id}.json").exists():
        return REJECTED_BEFORE
    return NEW


def planned_seeds(out_dir: Optional[Path], split: str, base: int, n: int, *, limit: int = 100_000) -> list[SeedStep]:
    """The seeds from ``base`` as a run of ``n`` scenes meets them, up to the ``n``-th kept or drawn one
    (``out_dir`` None or missing: seeds base .. base+n-1, all new). ``limit`` bounds the walk."""
    from mixcount.scene.sampler import scene_id_for

    steps: list[SeedStep] = []
    counted, seed = 0, base
    have_out = out_dir is not None and (Path(out_dir) / "scenes").is_dir()
    while counted < n and seed < base + limit:
        sid = scene_id_for(seed)
        state = seed_state(Path(out_dir), sid, split) if have_out and out_dir is not None else NEW
        steps.append(SeedStep(seed, sid, state))
        counted += state in COUNTED
        seed += 1
    return steps


def describe_passed(steps: list[SeedStep]) -> list[str]:
    """Readable lines for the seeds a run will not draw (kept, passed over), grouped by state."""
    words = {KEPT: "already finished in the output folder, kept (not drawn again)",
             OTHER_SPLIT: "finished scenes of another split, passed over",
             REJECTED_BEFORE: "thrown away by an earlier run (scenes/.rejected/), passed over",
             DAMAGED: "damaged: set aside and drawn again"}
    lines = []
    for state, text in words.items():
        ids = [s.scene_id for s in steps if s.state == state]
        if ids:
            shown = ", ".join(ids[:6]) + (f" and {len(ids) - 6} more" if len(ids) > 6 else "")
            lines.append(f"{len(ids)} seed(s) {text}: {shown}")
    return lines


@dataclass
class DryPlan:
    """What a run of ``n`` scenes would do with ``OUT`` as it is: the specs it draws, the seeds it passes
    over or keeps, and the seeds whose sampling fails (the run records those as failed and draws on)."""

    specs: list[Any] = field(default_factory=list)
    passed: list[SeedStep] = field(default_factory=list)  # kept, other split, rejected before
    kept: int = 0
    unsampled: list[tuple[int, str]] = field(default_factory=list)  # (seed, error)


def dry_plan(out_dir: Optional[Path], split: str, base: int, n: int, sample: Callable[[int], Any],
             max_attempts: int) -> DryPlan:
    """The run's walk without rendering: kept scenes count towards ``n`` as in the run, drawn seeds are
    sampled with ``sample(seed)``; at most ``max_attempts`` failed samplings (the run's bound)."""
    plan = DryPlan()
    start = base
    while plan.kept + len(plan.specs) < n and len(plan.unsampled) < max_attempts:
        steps = planned_seeds(out_dir, split, start, n - plan.kept - len(plan.specs))
        if not steps:
            break
        for st in steps:
            if st.state not in DRAWN:
                plan.passed.append(st)
                plan.kept += st.state == KEPT
                continue
            try:
                plan.specs.append(sample(st.seed))
            except Exception as exc:  # noqa: BLE001 - the run records such a seed as failed and draws the next
                plan.unsampled.append((st.seed, str(exc)))
        start = steps[-1].seed + 1
    return plan
