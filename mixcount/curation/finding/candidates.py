"""Candidate pairs for `catalog filter`: a descriptor index instead of every pair.

Comparing every pair costs n^2 / 2 comparisons (112 million for 15,000 objects); most pairs differ at a
glance. Each object gets a small feature vector that a copy keeps (rotation-, unit- and
resolution-free, and moved only a little by a squash of up to 25 % along one axis):

* the log ratios of its principal RMS spreads (second / first, third / first);
* :data:`RADIAL_QUANTILES` quantiles of the distance of its surface samples to their centroid, in RMS radii;
* its mean surface colour (RGB 0..1) times :data:`COLOUR_WEIGHT`: a weak pull, so that among shapes
  alike the same-coloured ones come first, never a gate.

A squash moves the vector more than anything else, so each object also asks the index with the vectors
it would have squashed or stretched (:data:`SQUASHES`) along each of its principal axes (:func:`queries`).

A k-d tree (scipy ``cKDTree``) over the vectors gives each object its ``k`` nearest neighbours (build
O(n log n), each query O(log n)): the candidate pairs are the union of those, plus every pair that
shares a content or geometry hash (identical files are always compared). The expensive rules run on
candidates only, so the work grows as n log n + k n. bench/candidates.py measures it at 1,500 and
15,000 objects."""

from __future__ import annotations

from collections import defaultdict
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

RADIAL_QUANTILES = 4
COLOUR_WEIGHT = 0.25
SQUASHES = (0.8, 0.9, 1.11, 1.25)  # each object also asks the index as if squashed / stretched along each principal axis


def _principal(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=0)
    _, vec = np.linalg.eigh(p.T @ p / max(len(p), 1))
    return p @ vec


def queries(points: np.ndarray, colours: np.ndarray | None) -> np.ndarray:
    """(1 + 12, d): the object's index vector, then the vectors it would have squashed or stretched by
    :data:`SQUASHES` along each principal axis: a copy squashed by a re-export lies near one of them."""
    p = _principal(points)
    out = [feature(p, colours)]
    for axis in range(3):
        for f in SQUASHES:
            s = np.ones(3)
            s[axis] = f
            out.append(feature(p * s, colours))
    return np.asarray(out)


def feature(points: np.ndarray, colours: np.ndarray | None) -> np.ndarray:
    """The index vector of one object's surface samples (see the module doc)."""
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(axis=0)
    eig = np.sort(np.linalg.eigvalsh(p.T @ p / max(len(p), 1)))[::-1]
    spread = np.sqrt(np.maximum(eig, 1e-30))
    rms = float(np.sqrt(max(eig.sum(), 1e-30)))
    radial = np.linalg.norm(p, axis=1) / rms
    q = np.quantile(radial, (np.arange(RADIAL_QUANTILES) + 0.5) / RADIAL_QUANTILES)
    mean = np.asarray(colours, dtype=np.float64).mean(axis=0) if colours is not None and len(colours) else np.full(3, 0.5)
    return np.concatenate([np.log(spread[1:] / spread[0]), q, COLOUR_WEIGHT * mean])


def candidate_pairs(features: np.ndarray, *, k: int, hashes: Sequence[Sequence[str | None]] = (),
                    extra: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Index pairs (i < j) to compare: each row's ``k`` nearest rows, and rows sharing any hash.

    ``features``: (n, d); ``extra``: optional (n, m, d) more query vectors per row (:func:`queries`), each
    asking for its ``k // 4`` nearest; ``hashes``: per row, hash strings (content, geometry; None is ignored)."""
    f = np.asarray(features, dtype=np.float64)
    n = len(f)
    pairs: set[tuple[int, int]] = set()
    if n >= 2 and k > 0:
        kk = min(k + 1, n)
        tree = cKDTree(f)
        _, idx = tree.query(f, k=kk)
        i, j = np.repeat(np.arange(n), kk), np.asarray(idx).reshape(-1)
        if extra is not None:  # the squash queries ask for fewer neighbours each
            ke = min(max(1, k // 4) + 1, n)
            more = np.asarray(extra, dtype=np.float64)
            _, idx2 = tree.query(more.reshape(-1, f.shape[1]), k=ke)
            i = np.concatenate([i, np.repeat(np.arange(n), more.shape[1] * ke)])
            j = np.concatenate([j, np.asarray(idx2).reshape(-1)])
        keep = (j != i) & (j < n)
        code = np.unique(np.minimum(i[keep], j[keep]).astype(np.int64) * n + np.maximum(i[keep], j[keep]))
        pairs.update(zip((code // n).tolist(), (code % n).tolist()))
    by_hash: dict[str, list[int]] = defaultdict(list)
    for i, hs in enumerate(hashes):
        for h in hs:
            if h:
                by_hash[h].append(i)
    for rows in by_hash.values():
        for a in range(len(rows)):
            for b in range(a + 1, len(rows)):
                pairs.add((min(rows[a], rows[b]), max(rows[a], rows[b])))
    return sorted(pairs)
