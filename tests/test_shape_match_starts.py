"""The shape alignment's two shortcuts (issue 58, the suite's time) give what the plain computation gives:
``best_starts`` against scoring every start's coarse chamfer and sorting, ``refine``'s early stop against all
:data:`~mixcount.curation.finding.shape_match.ICP_STEPS` steps. Shapes with distinct and with tied principal
moments (a box, a can, a ball: up to 384 starts), copies (turned, squashed, resampled) and strangers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from mixcount.curation.finding import portable_linalg as L
from mixcount.curation.finding import shape_match as S


def _shapes() -> list[S.Normalised]:
    meshes = [trimesh.creation.box((0.1, 0.2, 0.3)), trimesh.creation.cylinder(0.03, 0.1),
              trimesh.creation.icosphere(radius=0.05), trimesh.creation.capsule(0.1, 0.02),
              trimesh.creation.annulus(0.02, 0.05, 0.03), trimesh.creation.cone(0.04, 0.12)]
    rng = np.random.default_rng(5)
    squash = np.diag([1.0, 1.0, 0.8]) @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
    meshes.append(trimesh.Trimesh(meshes[5].vertices @ squash.T * 100.0, meshes[5].faces))  # a turned, squashed cone in cm
    return [S.normalise(trimesh.sample.sample_surface(m, 3000, seed=k)[0]) for k, m in enumerate(meshes)]


def _every_start(ca: np.ndarray, cb: np.ndarray, rotations: list[np.ndarray], spread: np.ndarray,
                 max_squash: float, keep: int) -> list[int]:
    """The plain computation: every start's coarse chamfer, a stable sort, the first ``keep``."""
    tree = cKDTree(ca)
    scores = []
    for rot in rotations:
        moved = L.turn(cb, rot)
        s = np.clip(spread / np.maximum(np.sqrt((moved ** 2).mean(axis=0)), 1e-9), 1.0 / max_squash, max_squash)
        scores.append(S.chamfer(ca, moved * s, tree))
    return sorted(range(len(rotations)), key=lambda k: scores[k])[:keep]


def _all_steps(pa: np.ndarray, tree_a: cKDTree, pb: np.ndarray, rot: np.ndarray, max_squash: float) -> np.ndarray:
    """ICP for every one of the ICP_STEPS steps, no early stop."""
    m = rot.copy()
    for _ in range(S.ICP_STEPS):
        _, idx = tree_a.query(L.turn(pb, m))
        fit = L.lstsq3(pb, pa[idx])
        u, s, vt = L.svd3(fit.T)
        if L.det3(L.mat(u, vt)) < 0:
            u[:, 2] *= -1
        s = s / float(L.root(np.prod(np.clip(s, 1e-6, None)), 3))
        m = L.mat(L.mat(u, np.diag(np.clip(s, 1.0 / max_squash, max_squash))), vt)
    return m


@pytest.fixture(scope="module")
def shapes() -> list[S.Normalised]:
    return _shapes()


def test_best_starts_are_the_best_of_every_start(shapes):
    counts = set()
    for a in shapes:
        for b in shapes:
            rotations = S.starts(a, b)
            counts.add(len(rotations))
            ca, cb = a.points[:S.COARSE], b.points[:S.COARSE]
            got = S.best_starts(ca, cb, rotations, a.spread, 1.25, S.REFINE_TOP)
            assert got == _every_start(ca, cb, rotations, a.spread, 1.25, S.REFINE_TOP)
    assert min(counts) == 24 and max(counts) > 200  # distinct moments and tied ones were both met


def test_refine_stops_early_only_where_the_rest_would_change_nothing(shapes):
    stopped = 0
    for a, b in [(shapes[0], shapes[0]), (shapes[5], shapes[6]), (shapes[1], shapes[3]), (shapes[2], shapes[4])]:
        fa, fb = a.points[:S.FINE], b.points[:S.FINE]
        tree = cKDTree(fa)
        for k in _every_start(a.points[:S.COARSE], b.points[:S.COARSE], S.starts(a, b), a.spread, 1.25, 2):
            rot = S.starts(a, b)[k]
            m = S.refine(fa, tree, fb, rot, 1.25)
            assert np.array_equal(m, _all_steps(fa, tree, fb, rot, 1.25))
            stopped += 1
    assert stopped == 8
