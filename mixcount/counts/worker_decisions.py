"""The count target's decisions in the worker (numpy only, no bpy; issue 37): which settled bodies rest on
which, which surplus counted bodies may be taken out, and whether a scene ended on its target.

A body may be taken out only when nothing rests on it, so every body left lies where physics put it: no
object floats after a neighbour is removed. "B rests on A" is read from the settled world boxes,
conservatively (more pairs than real contacts, never fewer): their XY boxes overlap (grown by ``tol``), B's
centre is higher than A's and B's bottom is no higher than A's top + ``tol``. Taking a body out never lowers
another body's visibility (the id pass records the first surface along each ray), so the kept objects
stay above v_t; the worker measures them again anyway.

The engine-side steps that act on these decisions: :mod:`mixcount.engine.count_trim` (the take-out) and
:mod:`mixcount.engine.count_topup` (the reserve, the rest check and the top-up).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import NDArray

Array = NDArray[Any]

COUNT_SURPLUS = "count_surplus"  # drop reason: a counted body beyond its class's target that supported nothing


def rests_on(lo: Array, hi: Array, tol: Array) -> Array:
    """(N, N) bool: ``out[a, b]`` when body b may rest on body a (see the module docstring); ``lo``/``hi``
    are the (N, 3) world boxes, ``tol`` (N,) each body's contact tolerance (the pair uses the larger)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    t = np.maximum(np.asarray(tol, dtype=np.float64)[:, None], np.asarray(tol, dtype=np.float64)[None, :])
    overlap_xy = ((lo[None, :, 0] <= hi[:, None, 0] + t) & (lo[:, None, 0] <= hi[None, :, 0] + t)
                  & (lo[None, :, 1] <= hi[:, None, 1] + t) & (lo[:, None, 1] <= hi[None, :, 1] + t))
    cz = (lo[:, 2] + hi[:, 2]) / 2
    higher = cz[None, :] > cz[:, None]
    touching = lo[None, :, 2] <= hi[:, None, 2] + t
    out = overlap_xy & higher & touching
    np.fill_diagonal(out, False)
    return np.asarray(out)


def hull_distance(points_world: Array, matrix_world: Array, equations: Array) -> float:
    """The smallest signed distance (world metres, > 0 outside) of ``points_world`` (K, 3) to a body's
    convex hull (local half-space ``equations``, pose ``matrix_world`` with a uniform scale): the largest
    plane distance per point, a lower bound of the true outside distance (so contacts are never missed)."""
    m = np.asarray(matrix_world, dtype=np.float64)
    inv = np.linalg.inv(m)
    local = np.asarray(points_world, dtype=np.float64) @ inv[:3, :3].T + inv[:3, 3]
    scale = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
    signed = local @ equations[:, :3].T + equations[:, 3]
    return float(signed.max(axis=1).min() * scale)


def rests_on_hulls(points_world: Sequence[Array], matrices: Sequence[Array], equations: Sequence[Array],
                   lo: Array, hi: Array, tol: Array) -> Array:
    """(N, N) bool: ``out[a, b]`` when body b may rest on body a, from the shapes that collided (each body's
    hull points in the world and its hull equations): the boxes' pairs of :func:`rests_on` whose hulls
    come within ``tol`` of each other (either's points near the other's hull)."""
    out = rests_on(lo, hi, tol)
    # each body's inverse pose and scale once (a dense pile has ~10 candidate pairs per body)
    inverses = [np.linalg.inv(np.asarray(m, dtype=np.float64)) for m in matrices]
    scales = [float(np.cbrt(abs(np.linalg.det(np.asarray(m, dtype=np.float64)[:3, :3])))) for m in matrices]

    def distance(points: Array, body: int) -> float:
        inv, eq = inverses[body], equations[body]
        local = points @ inv[:3, :3].T + inv[:3, 3]
        return float((local @ eq[:, :3].T + eq[:, 3]).max(axis=1).min() * scales[body])

    for a, b in zip(*np.nonzero(out)):
        t = max(float(tol[a]), float(tol[b]))
        if not (distance(points_world[b], a) <= t or distance(points_world[a], b) <= t):
            out[a, b] = False
    return out


def surplus_to_remove(classes: Sequence[int], targets: Mapping[int, int], resting: Array,
                      rng: np.random.Generator) -> tuple[list[int], dict[int, int]]:
    """Bodies to take out so each class keeps its target: repeatedly a random body (``rng``) of a class
    still over its target on which no remaining body rests. ``classes`` is each body's class index (-1:
    not counted, never removed), ``resting`` the :func:`rests_on` matrix. Returns the removed body
    indices in order and, per class, the surplus that could not be taken out (every candidate held
    something up)."""
    classes = [int(c) for c in classes]
    alive = np.ones(len(classes), dtype=bool)
    kept = {c: 0 for c in targets}
    for c in classes:
        if c in kept:
            kept[c] += 1
    surplus = {c: max(0, kept[c] - int(targets[c])) for c in targets}
    removed: list[int] = []
    cls = np.asarray(classes, dtype=int)
    resting = np.asarray(resting, dtype=bool)
    held = resting.sum(axis=1)  # per body: how many remaining bodies rest on it
    while any(surplus.values()):
        over = [c for c, s in surplus.items() if s > 0]
        free = np.flatnonzero(alive & (held == 0) & np.isin(cls, over))
        if len(free) == 0:
            break
        pick = int(free[int(rng.integers(len(free)))])
        alive[pick] = False
        held -= resting[:, pick]  # the bodies it rested on hold one body less
        removed.append(pick)
        surplus[classes[pick]] -= 1
    return removed, {c: s for c, s in surplus.items() if s > 0}


def count_verdict(targets: Mapping[int, int], kept: Mapping[int, int], short_total: int,
                  short_class: int) -> Optional[str]:
    """None when the scene may be kept (its total within ``short_total`` of the target, no class more than
    ``short_class`` off), else "count_short" or "count_over" (the worker rejects the scene: regenerated)."""
    total_t = sum(int(v) for v in targets.values())
    total_k = sum(int(kept.get(c, 0)) for c in targets)
    worst = max((abs(int(kept.get(c, 0)) - int(t)) for c, t in targets.items()), default=0)
    if abs(total_k - total_t) <= short_total and worst <= short_class:
        return None
    return "count_short" if total_k < total_t or any(kept.get(c, 0) < t for c, t in targets.items()) else "count_over"


def pixels_needed(median_px: float, resolution: int, min_px: float) -> Optional[int]:
    """The image side at which the median kept object would cover ``min_px`` visible pixels, or None when
    it already does (pixels grow with the square of the side)."""
    if median_px >= min_px:
        return None
    if median_px <= 0:
        return -1
    return int(np.ceil(resolution * np.sqrt(min_px / median_px)))


COUNT_RESERVE = "count_reserve"  # drop reason: a reserve body a top-up never needed (it never entered the scene)


def short_classes(targets: Mapping[int, int], kept: Mapping[int, int]) -> dict[int, int]:
    """Per class still below its target: how many objects it lacks."""
    return {c: int(t) - int(kept.get(c, 0)) for c, t in targets.items() if int(kept.get(c, 0)) < int(t)}


def topup_draw(short: Mapping[int, int], available: Mapping[int, int],
               factor: Union[float, Mapping[int, float]]) -> dict[int, int]:
    """Reserve bodies to drop per short class: ceil(factor x lacking) + 1 (some land occluded or roll out of
    view; the surplus is taken out again), at most what the class holds in reserve. ``factor``: one for
    every class, or per class (:func:`topup_factors`)."""
    def f(c: int) -> float:
        return float(factor.get(c, 1.0)) if isinstance(factor, Mapping) else float(factor)

    return {c: min(int(available.get(c, 0)), int(np.ceil(f(c) * n - 1e-9)) + 1)
            for c, n in short.items() if available.get(c, 0) > 0}


def topup_factors(short: Mapping[int, int], gained: Mapping[int, float], least: float, most: float
                  ) -> dict[int, float]:
    """Bodies to drop per lacking object, per short class: 1 / the class's yield so far (``gained``: objects
    kept per body that entered the pile for it: the first settle's, then the last top-up's), within
    [``least``, ``most``]. Small bodies dropped onto a pile of larger ones land in its gaps, occluded: a
    class that kept 1 in 4 of its top-up bodies gets 4 per lacking object next time, not 1.5, and is made
    up in a round or two instead of running out of rounds."""
    out = {}
    for c in short:
        y = float(gained.get(c, 1.0 / least))
        out[c] = float(min(most, max(least, 1.0 / y if y > 0 else most)))
    return out


def drop_spots(lo_xy: Array, hi_xy: Array, top_z: float, sizes: Sequence[float],
               rng: np.random.Generator, room: Optional[tuple[Array, Array]] = None) -> Array:
    """(K, 3) positions to drop K bodies (``sizes``: their largest sides) onto a settled pile: a grid over the
    pile's XY box (``lo_xy``..``hi_xy``, shrunk by half a cell) with one cell per body of side 1.2 x the
    largest, cells in a random order (``rng``), layers stacked from half a cell above ``top_z``; a jitter
    of 0.1 cell. No two bodies overlap at their release, and each falls onto the pile.

    A pile's box too small for one layer of the K cells is first grown about its centre until it holds
    them, within ``room`` (an XY box the bodies must stay over: inside a container's walls) when given:
    five bodies dropped in a column over a 3-body pile came to rest mostly out of the camera's view
    (issue 48)."""
    side = np.asarray(sizes, dtype=np.float64)
    k = len(side)
    if k == 0:
        return np.zeros((0, 3))
    cell = 1.2 * float(side.max())
    lo_xy, hi_xy = _room_for(np.asarray(lo_xy, dtype=np.float64), np.asarray(hi_xy, dtype=np.float64), k, cell, room)
    lo = np.asarray(lo_xy, dtype=np.float64) + cell / 2
    hi = np.asarray(hi_xy, dtype=np.float64) - cell / 2
    mid = (np.asarray(lo_xy, dtype=np.float64) + np.asarray(hi_xy, dtype=np.float64)) / 2
    lo, hi = np.minimum(lo, mid), np.maximum(hi, mid)
    n_xy = np.maximum(1, np.floor((hi - lo) / cell).astype(int) + 1)
    # n points from lo to hi: at least one cell apart (n - 1 <= (hi - lo) / cell)
    xs = np.linspace(lo[0], hi[0], n_xy[0]) if n_xy[0] > 1 else np.array([mid[0]])
    ys = np.linspace(lo[1], hi[1], n_xy[1]) if n_xy[1] > 1 else np.array([mid[1]])
    grid = np.array([(x, y) for x in xs for y in ys])
    out = np.zeros((k, 3))
    per_layer = len(grid)
    for layer in range((k + per_layer - 1) // per_layer):
        cells = grid[rng.permutation(per_layer)]
        for j in range(min(per_layer, k - layer * per_layer)):
            row = layer * per_layer + j
            out[row, :2] = cells[j] + rng.uniform(-0.1, 0.1, 2) * cell
            out[row, 2] = float(top_z) + cell * (layer + 0.5)
    return out


def _room_for(lo: Array, hi: Array, k: int, cell: float, room: Optional[tuple[Array, Array]]) -> tuple[Array, Array]:
    """The XY box grown about its centre to hold ``k`` cells in one layer (side ceil(sqrt(k)) cells, plus
    the half cell the grid keeps from each border), never beyond ``room`` and never smaller than it was."""
    need = (math.ceil(math.sqrt(k)) + 1) * cell
    mid = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, need / 2)
    new_lo, new_hi = mid - half, mid + half
    if room is not None:
        new_lo = np.minimum(np.maximum(new_lo, np.asarray(room[0], dtype=np.float64)), lo)
        new_hi = np.maximum(np.minimum(new_hi, np.asarray(room[1], dtype=np.float64)), hi)
    return new_lo, new_hi


def displacements(before: Array, after: Array) -> Array:
    """Per body the distance (m) its origin moved between two (N, 4, 4) poses."""
    b, a = np.asarray(before, dtype=np.float64), np.asarray(after, dtype=np.float64)
    return np.asarray(np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1))
