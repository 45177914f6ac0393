"""Where the counted instances spawn and when they are released (see :mod:`mixcount.scene.sampler`):
positions inside the pile's ellipse without overlaps, release waves by height, and the ellipse's radius
along a direction. Split out of the sampler so that it reads by concern.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray


def spawn_positions(rng: np.random.Generator, radii: NDArray[Any], centre: NDArray[Any], semi: tuple[float, float],
                     yaw: float, z_range: tuple[float, float], tries: int, ellipse: bool,
                     stack: bool = True, base_z: Optional[float] = None) -> NDArray[Any]:
    """Uniform points in the (rotated) ellipse or square, heights in z_range; each instance takes the
    first of ``tries`` candidates whose bounding sphere misses the ones placed so far, else the
    candidate with the most clearance, lifted (``stack``) above the spheres already in its column.
    ``base_z`` (a real-size scene, whose bodies may be larger than the height range's low end): no
    candidate's bounding sphere reaches below it (a body that started inside the floor fell through it)."""
    n = len(radii)
    out = np.zeros((n, 3))
    if n == 0:
        return out
    c, s_ = math.cos(yaw), math.sin(yaw)
    if ellipse:
        r = np.sqrt(rng.random((n, tries)))
        t = rng.random((n, tries)) * 2 * math.pi
        lx, ly = semi[0] * r * np.cos(t), semi[1] * r * np.sin(t)
    else:
        lx = rng.uniform(-semi[0], semi[0], (n, tries))
        ly = rng.uniform(-semi[1], semi[1], (n, tries))
    cand = np.stack([centre[0] + c * lx - s_ * ly, centre[1] + s_ * lx + c * ly,
                     rng.uniform(z_range[0], z_range[1], (n, tries))], axis=2)
    if base_z is not None:
        cand[:, :, 2] = np.maximum(cand[:, :, 2], base_z + np.asarray(radii, dtype=np.float64)[:, None])
    out[0] = cand[0, 0]
    for i in range(1, n):
        # squared centre distances against squared sums of radii: no square roots unless no spot is free
        need = (radii[:i] + radii[i]) ** 2
        first = out[:i] - cand[i, 0]
        if (np.einsum("ij,ij->i", first, first) >= need).all():
            out[i] = cand[i, 0]
            continue
        diff = cand[i][:, None, :] - out[None, :i, :]
        d2 = np.einsum("tij,tij->ti", diff, diff)
        ok = np.flatnonzero((d2 >= need).all(axis=1))
        if len(ok):
            out[i] = cand[i, ok[0]]
            continue
        clearance = (np.sqrt(d2) - radii[:i]).min(axis=1) - radii[i]
        best = cand[i, int(np.argmax(clearance))].copy()
        if stack:
            # no free spot in the height range: stack above whatever this column already holds, so
            # dense scenes do not start interpenetrated (the physics engine would explode them)
            dxy = np.hypot(out[:i, 0] - best[0], out[:i, 1] - best[1])
            column = dxy < radii[:i] + radii[i]
            if column.any():
                best[2] = max(best[2], float((out[:i, 2][column] + radii[:i][column]).max() + radii[i]) * 1.0001)
        out[i] = best
    return out


def release_waves(positions: NDArray[Any], z_range: tuple[float, float], clearance: float,
                   interval: int) -> tuple[NDArray[Any], NDArray[Any]]:
    """Stacked spawn spots -> spots in the height range, released in waves.

    A body that :func:`spawn_positions` stacked ``w`` bands (a band = the height range) above the range
    is moved down ``w`` bands and up ``clearance`` (over the pile the earlier waves left), and released
    at frame ``1 + w * interval``; the others are released at frame 1. Bodies of one wave keep their
    relative positions, so they stay as clear of each other as the stacking made them; earlier waves
    have fallen away by the time a later one is released. Returns the new positions and release frames.
    """
    band = z_range[1] - z_range[0]
    out = np.array(positions, dtype=np.float64)
    if band <= 0 or len(out) == 0:
        return out, np.ones(len(out), dtype=int)
    wave = np.where(out[:, 2] > z_range[1], np.ceil((out[:, 2] - z_range[1]) / band), 0).astype(int)
    out[:, 2] -= wave * band - np.where(wave > 0, clearance, 0.0)
    return out, 1 + wave * int(interval)


def ellipse_radius(a: float, b: float, theta: float) -> float:
    return a * b / math.sqrt((b * math.cos(theta)) ** 2 + (a * math.sin(theta)) ** 2)
