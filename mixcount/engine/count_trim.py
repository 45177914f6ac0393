"""A scene brought to its count target in the worker (issue 37): after the visibility loop, the surplus
counted bodies that support nothing are taken out of the Blender scene, visibility is measured again and
the scene's count verdict recorded (a ``count_target`` diagnostic; ``count_short`` / ``count_over`` when the
scene cannot be kept). The decisions are :mod:`mixcount.counts.worker_decisions`'; this module only reads
the state and removes objects (bpy through :class:`~mixcount.engine.scene_build.SceneState`)."""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

import mixcount.scene_decisions as D
from mixcount.counts import worker_decisions as C
from mixcount.engine.scene_build import SceneState

# two bodies whose collision hulls come this close (x the larger size) may touch. Lax on purpose: bodies at
# rest lie up to 2 x physics.HULL_MARGIN apart (Bullet grows each hull by it), so a surplus body holding a
# neighbour up may go and the rest check lets that one fall; with the margins added, 2 of 12 scenes kept a
# surplus body too many (docs/scene.md, "Count targets" step 3)
CONTACT_TOLERANCE = 0.05
COUNT_TRIM_STREAM = 41  # which free surplus body goes first: default_rng([scene seed, COUNT_TRIM_STREAM])


def kept_per_class(state: SceneState, n_classes: int) -> dict[int, int]:
    """Kept counted objects per class index (every class of ``n_classes``, 0 when none is kept)."""
    kept = {c: 0 for c in range(n_classes)}
    for i in state.kept("counted"):
        kept[int(state.objects[i].class_index)] += 1
    return kept


def resting_graph(state: SceneState, indices: list[int]) -> np.ndarray:
    """(N, N) bool over the bodies ``indices`` at their recorded poses (``matrix_world``; a body dropped
    since keeps the pose it had): ``out[a, b]`` when body b may rest on body a
    (:func:`mixcount.counts.worker_decisions.rests_on_hulls` of the shapes that collided: the proxies'
    points, else the hull of the mesh, kept per asset)."""
    n = len(indices)
    lo = np.zeros((n, 3))
    hi = np.zeros((n, 3))
    mats = [np.asarray(state.objects[i].matrix_world, dtype=np.float64) for i in indices]
    for row, i in enumerate(indices):
        lo[row], hi[row] = D.world_bounds(state.cache.columns[state.objects[i].asset], mats[row])
    tol = np.array([CONTACT_TOLERANCE * float(state.objects[i].size_m) for i in indices])
    points = [np.asarray(state.cache.collider_points(state.objects[i].asset), dtype=np.float64)
              @ mats[row][:3, :3].T + mats[row][:3, 3] for row, i in enumerate(indices)]
    eqs = [state.cache.hull(state.objects[i].asset) for i in indices]
    return np.asarray(C.rests_on_hulls(points, mats, eqs, lo, hi, tol), dtype=bool).reshape(n, n)


def remove_surplus(state: SceneState) -> list[int]:
    """Take out, per class, the counted bodies beyond its target on which nothing rests (kept counted
    objects and distractors alike are considered resting bodies); returns the bodies taken out."""
    target = state.spec.count_target
    assert target is not None
    targets = {ci: int(n) for ci, n in enumerate(target["per_class"])}
    # distractors placed after physics stand on free floor beside the pile: nothing rests on them and they
    # rest on nothing counted, so they take no part (their hulls are captures' hulls: seconds a scene)
    kept = state.kept("counted") if state.placed_after_physics else state.kept()
    if not kept:
        return []
    classes = [int(state.objects[i].class_index) if state.objects[i].role == "counted" else -1 for i in kept]
    resting = resting_graph(state, kept)
    rng = np.random.default_rng([int(state.spec.seed), COUNT_TRIM_STREAM])
    removed, left = C.surplus_to_remove(classes, targets, resting, rng)
    for row in removed:
        state.drop(kept[row], C.COUNT_SURPLUS, "count_target")
    if left:
        state.diagnostics.append({"kind": "count_surplus_held", "per_class": {str(c): s for c, s in left.items()}})
    return [kept[row] for row in removed]


def count_outcome(state: SceneState, removed: int, resolution: int, *, topped_up: int = 0, topup_rounds: int = 0,
                  reserve_unused: int = 0) -> Optional[str]:
    """The ``count_target`` diagnostic (target, kept and surplus removed per class, the reserve bodies a
    top-up dropped in and its rounds, the reserve never used; the median visible pixels of a kept counted
    object and, below the target's ``min_object_px``, the image side needed) and the verdict: None, or the
    reason the scene cannot be kept."""
    target = state.spec.count_target
    assert target is not None
    targets = {ci: int(n) for ci, n in enumerate(target["per_class"])}
    kept = kept_per_class(state, len(targets))
    verdict = C.count_verdict(targets, kept, int(target["short_total"]), int(target["short_class"]))
    px = [float(state.objects[i].visible_px or 0) for i in state.kept("counted")]
    median_px = float(np.median(px)) if px else 0.0
    record: dict[str, Any] = {
        "kind": "count_target", "total": int(target["total"]), "kept": sum(kept.values()),
        "per_class_target": [targets[c] for c in sorted(targets)], "per_class_kept": [kept[c] for c in sorted(kept)],
        "surplus_removed": int(removed), "topped_up": int(topped_up), "topup_rounds": int(topup_rounds),
        "reserve_unused": int(reserve_unused), "verdict": verdict or "ok", "median_visible_px": round(median_px, 1)}
    min_px = target.get("min_object_px")
    if min_px is not None:
        need = C.pixels_needed(median_px, resolution, float(min_px))
        if need is not None:
            record["too_small"] = {"min_object_px": float(min_px), "resolution_needed": need}
    state.diagnostics.append(record)
    return verdict
