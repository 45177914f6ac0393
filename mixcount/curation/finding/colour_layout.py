"""Distances between two surfaces' principal-frame colour grids (:mod:`mixcount.curation.finding.appearance3d`
builds the looks and their grids): the colour layout distance with its rotation search, the colour
*pattern* correlation, and the axis-normalised shape distance of colourless looks with the mirror
asymmetry that says when it proves anything.

Apart from appearance3d because the two change for different reasons: the looks are what is cached per
object (``APPEARANCE_VERSION``), these distances what the filter caches per pair (``LAYOUT_VERSION``).
"""

from __future__ import annotations

import numpy as np

from mixcount.curation.finding.appearance3d import SEED, SurfaceLook, colour_grids, principal_frames

LAYOUT_VERSION = "layout-v1"  # the layout distance (cached per pair by catalog filter)
SEARCH_SUBSAMPLE = 4  # the coarse rotation search grids every 4th sample (1,500), the refinement all


def _grid_distances(ga: np.ndarray, gbs: np.ndarray) -> np.ndarray:
    """Layout distance of grid ``ga`` to each grid of ``gbs`` (frames first): the count-weighted mean
    colour difference over the cells either covers, a cell only one side covers counting by how much
    that side has there."""
    ca, cb = ga[None, ..., 3], gbs[..., 3]
    top = np.maximum(ca.max(), cb.reshape(len(gbs), -1).max(axis=1)).reshape(-1, 1, 1, 1)
    eps = 1e-4 * top
    both = (ca > eps) & (cb > eps)
    either = (ca > eps) | (cb > eps)
    ma = ga[None, ..., :3] / np.maximum(ca, 1e-12)[..., None]
    mb = gbs[..., :3] / np.maximum(cb, 1e-12)[..., None]
    diff = np.where(both, np.abs(ma - mb).mean(axis=-1), 1.0)
    weight = np.where(either, np.minimum(ca + cb, 2 * top), 0.0)
    occupancy = np.abs(ca - cb) / np.maximum(ca + cb, 1e-12)
    diff = np.where(both, np.maximum(diff, occupancy), diff)
    return (diff * weight).reshape(len(gbs), -1).sum(axis=1) / np.maximum(weight.reshape(len(gbs), -1).sum(axis=1), 1e-12)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def _search_frames(look: SurfaceLook) -> list[np.ndarray]:
    """Frames to search when the shape leaves axes open: turns about the distinct axis in 10-degree
    steps (both ways up) for two tied moments; a fixed set of 600 rotations for three."""
    from scipy.spatial.transform import Rotation

    basis = look.basis
    if any(len(g) == 3 for g in look.tied):
        return [basis @ r for r in Rotation.random(600, random_state=SEED).as_matrix()]
    if look.tied:
        g = look.tied[0]
        k = next(i for i in range(3) if i not in g)
        flips = [np.eye(3)]
        flip = np.eye(3)
        flip[k, k] = -1
        flip[g[0], g[0]] = -1
        flips.append(flip)
        out = []
        for f in flips:
            for step in range(36):
                out.append(_rotation(basis[:, k], np.radians(10.0 * step)) @ basis @ f)
        return out
    return []


def _refine(a: np.ndarray, b: SurfaceLook, frame: np.ndarray, best: float) -> float:
    """Local search around ``frame``: the best of six small turns (about each axis, both ways) while it
    improves, then the step halved (4 rounds)."""
    step = np.radians(8.0)
    for _ in range(4):
        while True:
            cands = [_rotation(frame @ axis, sign * step) @ frame for axis in np.eye(3) for sign in (1, -1)]
            scores = _grid_distances(a, colour_grids(b.points, b.colours, cands))
            k = int(np.argmin(scores))
            if not scores[k] < best - 1e-6:
                break
            best, frame = float(scores[k]), cands[k]
        step /= 2
    return best


def layout_distance(a: SurfaceLook, b: SurfaceLook, *, search_above: float | None = None) -> float:
    """Principal-frame colour layout distance in [0, 1]: the best match of ``a``'s first frame with
    any of ``b``'s candidate frames, and of ``b``'s first with ``a``'s (symmetric).

    With ``search_above``, a distance still above it for a shape whose principal moments tie (a can's
    cross-section, a cube, a ball: the axes are not defined by the shape) starts a rotation search of
    ``b`` against ``a``'s first frame, then a local refinement of the best turn."""
    best = float(_grid_distances(a.grids[0], b.grids).min())
    best = min(best, float(_grid_distances(b.grids[0], a.grids).min()))
    if search_above is None or best <= search_above or not b.tied:
        return best
    frames = _search_frames(b)
    coarse = slice(None, None, SEARCH_SUBSAMPLE)  # every 4th sample for the coarse search; refined on all
    scores = _grid_distances(a.grids[0], colour_grids(b.points[coarse], b.colours[coarse], frames))
    k = int(np.argmin(scores))
    start = float(_grid_distances(a.grids[0], colour_grids(b.points, b.colours, [frames[k]]))[0])
    best = min(best, start)
    return min(best, _refine(a.grids[0], b, frames[k], start))


def refined_layout_distance(a: SurfaceLook, b: SurfaceLook) -> float:
    """:func:`layout_distance` with a local rotation refinement of ``b``'s best principal frame, also where
    the principal moments are distinct. A copy flattened along an axis that is not a principal axis (a
    re-export squashing the model's up axis) has its principal axes tilted by a few degrees, which moves
    colours across cells; the refinement turns them back (cross-source copies, :mod:`mixcount.curation.finding.catalog_filter`)."""
    frames, _ = principal_frames(b.points, b.colours)
    scores = _grid_distances(a.grids[0], b.grids)
    k = int(np.argmin(scores))
    best = min(float(scores[k]), layout_distance(a, b))
    return min(best, _refine(a.grids[0], b, frames[k], float(scores[k])))


def _cell_colours(grid: np.ndarray, min_share: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean colour per cell of a colour grid, and which cells hold at least ``min_share`` of the samples."""
    count = grid[..., 3].ravel()
    colour = grid[..., :3].reshape(-1, 3) / np.maximum(count, 1e-12)[:, None]
    return colour, count >= min_share


def pattern_correlation(a: SurfaceLook, b: SurfaceLook, *, min_share: float = 1e-3) -> float:
    """How well ``a``'s colour *pattern* repeats on ``b`` whatever the colours: the correlation of the
    two surfaces' cell-to-cell colour differences over the principal-frame cells both cover (a Mantel
    statistic), best over ``b``'s candidate frames. A recolour (a hue turned, another material on the
    same print) keeps which cells differ from which, so it keeps the correlation high (0.69-0.83 for a
    hue-turned, decimated, flattened bunny scan) where the colour layout itself is far apart; -1 when
    fewer than 10 cells are shared or a surface has no pattern."""
    colour_a, cover_a = _cell_colours(a.grids[0], min_share)
    best = -1.0
    for grid in b.grids:
        colour_b, cover_b = _cell_colours(grid, min_share)
        both = cover_a & cover_b
        if both.sum() < 10:
            continue
        upper = np.triu_indices(int(both.sum()), 1)
        da = np.linalg.norm(colour_a[both][:, None] - colour_a[both][None], axis=-1)[upper]
        db = np.linalg.norm(colour_b[both][:, None] - colour_b[both][None], axis=-1)[upper]
        if da.std() < 1e-9 or db.std() < 1e-9:
            continue
        best = max(best, float(np.corrcoef(da, db)[0, 1]))
    return best


# --------------------------------------------------------------------------- shape in the principal frame


def shape_only(look: SurfaceLook) -> SurfaceLook:
    """``look`` with every sample one grey: its grids hold where the surface lies in the principal frame
    (each axis scaled to its extent) and nothing of its colours. Two such grids differ only by occupancy,
    so their :func:`layout_distance` is an *axis-normalised* shape distance."""
    return SurfaceLook(look.points, np.full_like(look.colours, 0.5), look.basis, look.tied, look.symmetric_axes)


def occupancy_distance(a: SurfaceLook, b: SurfaceLook) -> float:
    """Axis-normalised shape distance of two :func:`shape_only` looks: where the surfaces lie once each
    principal axis is scaled to the extent along it, after a local rotation refinement both ways
    (:func:`refined_layout_distance`). A re-export flattening one axis by 10-25 % scales that axis only,
    which the per-axis normalisation takes out (a squash across the principal axes tilts them a few
    degrees: the refinement turns them back); units and orientation never mattered. Measured: the plain
    cow scan against its copies decimated to 4-5 %, flattened 15-22 %, in another colour 0.027-0.032;
    the textured bunny's flattened copies 0.022-0.075; the bunny against the cow 0.138-0.169, against
    the airplane 0.24 (docs/curation.md). Every box, ball or cylinder is the same after the scaling,
    which is why look_rules.py asks for :func:`mirror_asymmetry` first."""
    return min(refined_layout_distance(a, b), refined_layout_distance(b, a))


def mirror_asymmetry(look: SurfaceLook) -> list[float]:
    """Per principal axis (moments descending): the occupancy distance between the shape's grid and its
    mirror image across the plane normal to that axis; ~0.01-0.02 where the shape is mirror-symmetric
    there (a box, a can, an egg, a bone), 0.1-0.35 where it is not (a cow: head and tail, back and legs;
    an airplane). A shape symmetric about two or three of its principal planes is one of a family that
    the per-axis scaling makes identical (every box is a cube then), so an axis-normalised match proves
    nothing for it."""
    grid = shape_only(look).grids[0]
    return [float(_grid_distances(grid, np.flip(grid, axis=axis)[None])[0]) for axis in range(3)]
