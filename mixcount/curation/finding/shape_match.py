"""Shape agreement of two objects whatever their resolution, units, pose and a squash along one axis.

Used by the copy rule (:mod:`mixcount.curation.finding.copy_rules`) on candidate pairs only (the index in
:mod:`mixcount.curation.finding.candidates` picks them). From each object's surface samples (the area-weighted
points of :func:`mixcount.curation.finding.appearance3d.load_samples`, colours ignored):

1. **Normalise**: centre on the centroid, turn into the principal frame, divide by the RMS radius
   (units, size and pose out; resolution does not matter, the samples are area-weighted).
2. **Every axis order and sign**: the 24 proper rotations that permute and flip the principal axes. A
   principal frame fixes the axes only up to their order (two nearly tied moments swap from one export
   to the next: the genesis-world duck's 0.815 / 0.813) and sign; where two moments tie within
   :data:`TIE` the frame is also free to turn about the third axis, so those starts are repeated every
   :data:`TIE_STEP_DEG` degrees about it.
3. **Coarse score** of every start on :data:`COARSE` points (a symmetric chamfer), then **refine** the
   best :data:`REFINE_TOP` with a few ICP steps on :data:`FINE` points, each the least-squares linear map
   onto the nearest points with its stretches bounded to ``[1/max_squash, max_squash]`` along any axis,
   relative to their geometric mean (a re-export that flattened one axis by up to 25 % is the same shape).
4. **Distance**: the symmetric chamfer, the mean distance from each point to the nearest point of the
   other sample, both ways, averaged, in units of the RMS radius (0 for one shape; a sphere against a
   cube of the same RMS radius is about 0.05).
5. **Order-free** (issue 69): the starts, their coarse scores and ICP map one object onto the other, and
   the two directions differ (on 1,628 pairs of five catalogs by 0.032 at the 95th percentile), so
   :func:`match` always searches for the map of the object whose samples' digest (:attr:`Normalised.digest`,
   a function of the samples alone, not of a catalog's order) sorts later onto the other, then refines that
   map once more the other way round and keeps the lower distance: ``match(a, b)`` and ``match(b, a)`` give
   one distance, and the same library in another order gets the same figures. (The digest's direction alone
   lost a public copy at 0.076 against 0.070 the other way: docs/curation.md, "The search's direction".)
6. **The same bits on every machine**: every product, solve, eigen- and singular-vector here comes from
   :mod:`mixcount.curation.finding.portable_linalg` (no BLAS, LAPACK or transcendental functions), because
   ICP and the ranking of starts follow near-ties: with numpy's BLAS the figures followed the CPU's OpenBLAS
   kernels (docs/curation.md, "Figures that follow the machine").

A *shape-free* figure comes with it: the distance of each object to its nearest primitive (a box, three
rounded boxes (superellipsoids), an ellipsoid, a cylinder along each axis, under the same alignment with free per-axis scale). A box
against another box, a can against a can, agree as closely as copies do; the copy rule asks the pair to
agree much more closely than either object agrees with a primitive (its shape must carry evidence)."""

from __future__ import annotations

import bisect
import hashlib
from dataclasses import dataclass
from functools import lru_cache
from itertools import permutations, product

import numpy as np
from scipy.spatial import cKDTree

from mixcount.curation.finding import portable_linalg as L

MATCH_VERSION = "match-v5"  # cached distances are keyed by it (v5: no BLAS / LAPACK, the same bits on every machine; v4: the search polished the other way round; v3: one direction, at most WHOLE_STARTS)
COARSE = 250
FINE = 1500
REFINE_TOP = 3
WHOLE_STARTS = 48  # starts scored whole at most, in the order of their b-to-a half (issue 69: 69 -> 54 ms a pair)
ICP_STEPS = 10
TIE = 0.06  # principal RMS extents within 6 % of each other: the frame may turn about the third axis
TIE_STEP_DEG = 30.0
SEED = 20261204
NORMAL_NEIGHBOURS = 10
POINT_SHARE = 0.2
NO_SCALE = np.ones(3)  # refine folds the per-axis scale into its map; the scale applied after it is none
NO_SCALE.flags.writeable = False
QUANTILE = 0.5  # the default of [filter] match_quantile: the median of the point-to-plane distances


@dataclass(frozen=True)
class Normalised:
    """An object's samples in its principal frame, unit RMS radius, with the RMS extent per axis."""

    points: np.ndarray  # (n, 3)
    normals: np.ndarray  # (FINE, 3) unit normals of the first FINE points (local PCA of their neighbours)
    spread: np.ndarray  # RMS extent along each principal axis (descending), unit RMS radius overall
    tied: tuple[int, ...]  # axes about which the frame is free to turn (moments tied)
    digest: str = ""  # of the samples: which of two objects is aligned onto which (:func:`match`)


@dataclass(frozen=True)
class Match:
    distance: float  # symmetric chamfer in RMS radii after the best alignment
    scale: tuple[float, float, float]  # per-axis scale applied to the second object (first one's frame)
    rotation: np.ndarray  # 3x3, second object's normalised frame -> first one's (the stretch folded in)

    @property
    def stretch(self) -> float:
        """Largest over smallest stretch of the map (1.0: no squash; at most ``max_squash`` squared)."""
        s = L.svd3(self.rotation * np.asarray(self.scale)[None, :])[1]
        return float(s[0] / max(s[-1], 1e-12))


def normalise(points: np.ndarray) -> Normalised:
    """Centre, principal frame (descending moments), unit RMS radius; a fixed subsample order."""
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=0)
    cov = L.gram(p, p) / max(len(p), 1)
    eig, vec = L.sym_eig3(cov)
    order = np.argsort(eig)[::-1]
    eig, vec = eig[order], vec[:, order]
    if L.det3(vec) < 0:
        vec[:, 2] *= -1
    q = L.turn(p, vec.T)
    rms = float(np.sqrt(max(eig.sum(), 1e-30)))
    q = q / rms
    spread = np.sqrt(np.maximum(eig, 0.0)) / rms
    tied = tuple(k for k, (i, j) in enumerate(((1, 2), (0, 2), (0, 1)))
                 if abs(spread[i] - spread[j]) <= TIE * max(spread[i], spread[j]))
    rng = np.random.default_rng(SEED)
    q = q[rng.permutation(len(q))]
    digest = hashlib.blake2b(np.ascontiguousarray(q).tobytes(), digest_size=16).hexdigest()
    return Normalised(q, local_normals(q[:FINE], q), spread, tied, digest)


def local_normals(points: np.ndarray, cloud: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unit normal of each point: the least-spread direction of its ``k`` nearest cloud points."""
    k = min(k, len(cloud))
    _, idx = cKDTree(cloud).query(points, k=k)
    nb = cloud[idx] - cloud[idx].mean(axis=1, keepdims=True)
    _, vec = L.sym_eig3_many(np.einsum("nki,nkj->nij", nb, nb))
    return vec[:, :, 0]


@lru_cache(maxsize=1)
def signed_permutations() -> tuple[np.ndarray, ...]:
    """The 24 proper rotations that map the coordinate axes onto each other (any order, any sign)."""
    out = []
    for perm in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, s) in enumerate(zip(perm, signs)):
                m[row, col] = s
            if np.linalg.det(m) > 0:
                out.append(m)
    return tuple(out)


def _about(axis: int, deg: float) -> np.ndarray:
    c, s = L.cos_sin_deg(deg)
    i, j = [k for k in range(3) if k != axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def starts(a: Normalised, b: Normalised) -> list[np.ndarray]:
    """Candidate rotations (b's frame -> a's): every signed axis permutation, and where either frame
    is free about an axis, the same turned about that axis in steps."""
    base = list(signed_permutations())
    turns = sorted(set(a.tied) | set(b.tied))
    if not turns:
        return base
    extra = []
    for axis in turns:
        for deg in np.arange(TIE_STEP_DEG, 180.0, TIE_STEP_DEG):
            t = _about(axis, float(deg))
            extra.extend(L.mat(t, r) for r in base)
    return base + extra


def chamfer(p: np.ndarray, q: np.ndarray, tree_p: cKDTree | None = None, tree_q: cKDTree | None = None) -> float:
    """Symmetric mean nearest-neighbour distance of two point sets."""
    tp = tree_p if tree_p is not None else cKDTree(p)
    tq = tree_q if tree_q is not None else cKDTree(q)
    return 0.5 * (float(tq.query(p)[0].mean()) + float(tp.query(q)[0].mean()))


def surface_distance(a: Normalised, b: Normalised, rot: np.ndarray, scale: np.ndarray, *,
                     quantile: float = QUANTILE) -> float:
    """Symmetric point-to-plane distance of ``b`` (turned by ``rot``, scaled per axis) to ``a`` on
    :data:`FINE` points each: the distance of each point to the tangent plane at its nearest point of the
    other sample, plus :data:`POINT_SHARE` of the point distance (a far point whose neighbour's plane
    happens to pass through it still counts), its ``quantile`` each way (``[filter] match_quantile``),
    averaged. Unlike a point-to-point chamfer it has
    (almost) no floor from two independent samplings of one surface."""
    pa, na = a.points[:FINE], a.normals
    pb = L.turn(b.points[:FINE], rot) * scale
    nb = L.turn(b.normals, L.inv3(rot).T) / scale  # normals map by the inverse transpose
    nb /= np.linalg.norm(nb, axis=1, keepdims=True)
    d_ab, j = cKDTree(pb).query(pa)
    d_ba, i = cKDTree(pa).query(pb)
    plane_ab = np.abs(((pa - pb[j]) * nb[j]).sum(axis=1)) + POINT_SHARE * d_ab
    plane_ba = np.abs(((pb - pa[i]) * na[i]).sum(axis=1)) + POINT_SHARE * d_ba
    return 0.5 * float(np.quantile(plane_ab, quantile) + np.quantile(plane_ba, quantile))


def refine(pa: np.ndarray, tree_a: cKDTree, pb: np.ndarray, rot: np.ndarray, max_squash: float) -> np.ndarray:
    """ICP from ``rot`` with a linear map whose stretches are bounded: each step fits the least-squares
    linear map of b's points onto their nearest points of a, keeps its rotation parts and clips its
    singular values (relative to their geometric mean) to ``[1/max_squash, max_squash]``: a squash along
    *any* axis, not only a principal one. Returns the map, expressed in a's frame (rotation = U V^T, the
    scale along U's axes folded in, so the per-axis scale it is used with is :data:`NO_SCALE`).

    A step is a function of the nearest-point pairing alone, so once a step pairs every point as the step
    before did the map is final: the remaining steps would repeat it, and are skipped (same result)."""
    lo, hi = 1.0 / max_squash, max_squash
    m = rot.copy()
    previous: np.ndarray | None = None
    for _ in range(ICP_STEPS):
        moved = L.turn(pb, m)
        _, idx = tree_a.query(moved)
        if previous is not None and np.array_equal(idx, previous):
            break
        previous = idx
        target = pa[idx]
        fit = L.lstsq3(pb, target)  # pb @ fit ~ target
        u, s, vt = L.svd3(fit.T)
        if L.det3(L.mat(u, vt)) < 0:
            u[:, 2] *= -1
        s = s / float(L.root(np.prod(np.clip(s, 1e-6, None)), 3))  # over their geometric mean
        m = L.mat(L.mat(u, np.diag(np.clip(s, lo, hi))), vt)
    return m


def best_starts(ca: np.ndarray, cb: np.ndarray, rotations: list[np.ndarray], spread: np.ndarray,
                max_squash: float, keep: int, whole: int | None = None) -> list[int]:
    """Indices of the ``keep`` rotations with the lowest coarse :func:`chamfer` of ``ca`` against ``cb``
    turned by the rotation and given a first per-axis scale from the spreads (bounded, so a squashed copy
    starts close); ties keep the start order.

    The same ``keep`` as scoring every start, for less: half of a chamfer is the mean distance of b's
    points to a, which one query of a's k-d tree gives for every start at once, and the other half is never
    negative. Starts are scored whole in the order of that half, and the rest are passed over once that
    half alone exceeds the ``keep``-th best whole score (they could not enter the ``keep`` best).

    ``whole``: at most this many starts are scored whole (the first in that order; None: no bound). Where
    moments tie there are up to 384 starts and ~70 of them were scored whole; a bound of
    :data:`WHOLE_STARTS` moved 4 of 1,951 cached figures of five catalogs by less than 0.001 (docs/curation.md)."""
    tree_ca = cKDTree(ca)
    turned = L.turn_each(cb, np.stack(rotations))  # cb @ rot.T for every rotation at once
    scale = np.clip(spread / np.maximum(np.sqrt((turned ** 2).mean(axis=1)), 1e-9), 1.0 / max_squash, max_squash)
    moved = turned * scale[:, None, :]  # (rotations, points, 3): the same values as one rotation at a time
    to_a = tree_ca.query(moved.reshape(-1, 3))[0].reshape(len(rotations), len(cb)).mean(axis=1)
    scored: list[tuple[float, int]] = []  # (whole chamfer, start), kept sorted
    for n, k in enumerate(sorted(range(len(rotations)), key=lambda k: to_a[k])):
        if len(scored) >= keep and (0.5 * to_a[k] > scored[keep - 1][0] * (1.0 + 1e-9) or (whole is not None and n >= whole)):
            break
        to_b = float(cKDTree(moved[k]).query(ca)[0].mean())
        bisect.insort(scored, (0.5 * (to_b + float(to_a[k])), k))  # = chamfer(ca, moved[k], tree_ca)
    return [k for _, k in scored[:keep]]


def match(a: Normalised, b: Normalised, *, max_squash: float, quantile: float = QUANTILE,
          whole: int | None = WHOLE_STARTS) -> Match:
    """Best alignment of ``b`` onto ``a`` (see the module doc), the same whichever comes first: the
    object whose :attr:`~Normalised.digest` sorts later is aligned onto the other (the search), then the
    map found is refined once more the other way round, from its inverse, and the lower of the two
    distances is kept. The map is returned as ``b``'s frame -> ``a``'s either way."""
    first, second = (a, b) if a.digest <= b.digest else (b, a)
    found = _match(first, second, max_squash=max_squash, quantile=quantile, whole=whole)  # second -> first
    back = L.inv3(found.rotation * np.asarray(found.scale)[None, :])  # first -> second
    fs, ff = second.points[:FINE], first.points[:FINE]
    polished = refine(fs, cKDTree(fs), ff, back, max_squash)
    other = round(surface_distance(second, first, polished, NO_SCALE, quantile=quantile), 6)
    if other < found.distance:  # the map of `first` onto `second` is the better one
        aligned, aligned_is_b = Match(other, (1.0, 1.0, 1.0), polished), first is b
    else:
        aligned, aligned_is_b = found, second is b
    if aligned_is_b:
        return aligned
    inverse = L.inv3(aligned.rotation * np.asarray(aligned.scale)[None, :])
    return Match(aligned.distance, (1.0, 1.0, 1.0), inverse)


def _match(a: Normalised, b: Normalised, *, max_squash: float, quantile: float, whole: int | None) -> Match:
    """Best alignment of ``b`` onto ``a``, in this direction."""
    rotations = starts(a, b)
    top = best_starts(a.points[:COARSE], b.points[:COARSE], rotations, a.spread, max_squash, REFINE_TOP, whole)
    fa, fb = a.points[:FINE], b.points[:FINE]
    tree_fa = cKDTree(fa)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for k in top:
        r = refine(fa, tree_fa, fb, rotations[k], max_squash)
        got = (surface_distance(a, b, r, NO_SCALE, quantile=quantile), r, NO_SCALE)
        if best is None or got[0] < best[0]:
            best = got
    assert best is not None
    return Match(round(best[0], 6), tuple(float(v) for v in best[2]), best[1])  # type: ignore[arg-type]


def _primitive_samples(kind: str, spread: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Surface samples of a unit primitive (box, ellipsoid, cylinder along axis k), area-weighted."""
    if kind == "ellipsoid":
        v = rng.normal(size=(n * 3, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return v[:n]
    if kind.startswith("rounded"):  # a superellipsoid |x|^(2/e) + |y|^(2/e) + |z|^(2/e) = 1: a rounded box
        e = float(kind[len("rounded"):])
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        fifths = int(round(e * 5))  # |v| ** e as a power of the fifth root: e is 0.2, 0.4 or 0.6
        if abs(fifths - e * 5) > 1e-9:
            raise ValueError(f"rounded box exponent {e} is not a multiple of 0.2")
        return np.sign(v) * L.power(L.root(np.abs(v), 5), fifths)
    if kind == "box":
        face = rng.integers(0, 6, n)
        p = rng.uniform(-1, 1, (n, 3))
        p[np.arange(n), face // 2] = np.where(face % 2 == 0, 1.0, -1.0)
        return p
    axis = int(kind[-1])
    # a cylinder of radius 1, half-height 1: side 4 pi, caps 2 pi
    side = rng.random(n) < 2.0 / 3.0
    around = rng.normal(size=(n, 2))  # a uniform direction about the axis, without cos and sin
    around /= np.sqrt((around * around).sum(axis=1, keepdims=True))
    r = np.where(side, 1.0, np.sqrt(rng.random(n)))
    h = np.where(side, rng.uniform(-1, 1, n), np.where(rng.random(n) < 0.5, 1.0, -1.0))
    others = [k for k in range(3) if k != axis]
    p = np.empty((n, 3))
    p[:, axis] = h
    p[:, others[0]] = r * around[:, 0]
    p[:, others[1]] = r * around[:, 1]
    return p


PRIMITIVES = ("box", "rounded0.2", "rounded0.4", "rounded0.6", "ellipsoid", "cylinder0", "cylinder1", "cylinder2")


def primitive_distance(a: Normalised, *, quantile: float = QUANTILE) -> float:
    """Chamfer distance of the object to its nearest primitive (box, ellipsoid, cylinder along each
    principal axis), each stretched to the object's RMS spread per axis and then aligned as a copy would
    be with a free per-axis scale: how much of the shape a plain solid does *not* explain."""
    rng = np.random.default_rng(SEED)
    best = np.inf
    fa = a.points[:FINE]
    tree = cKDTree(fa)
    coarse_tree = cKDTree(a.points[:COARSE])
    # where moments tie the object's frame may sit at any angle about the tied axis: try turns there
    turns = [np.eye(3)] + [_about(axis, float(deg)) for axis in a.tied for deg in np.arange(15.0, 90.0, 15.0)]
    for kind in PRIMITIVES:
        p = _primitive_samples(kind, a.spread, 4 * FINE, rng)
        p = p - p.mean(axis=0)
        p = p * (a.spread / np.maximum(np.sqrt((p ** 2).mean(axis=0)), 1e-9))
        prim = normalise(p)
        start = min(turns, key=lambda t: chamfer(a.points[:COARSE], L.turn(prim.points[:COARSE], t), coarse_tree))
        r = refine(fa, tree, prim.points[:FINE], start, 2.0)
        best = min(best, surface_distance(a, prim, r, NO_SCALE, quantile=quantile))
    return round(float(best), 6)
