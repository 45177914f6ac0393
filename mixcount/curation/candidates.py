"""Candidate pairs for `catalog filter`: a descriptor index instead of every pair.

Comparing every pair costs n^2 / 2 comparisons (112 million for 15,000 objects); most pairs differ at a
glance. Each object gets a small feature vector that a copy keeps (rotation-, unit- and
resolution-free, and moved only a little by a squash of up to 25 % along one axis):

* the log ratios of its principal RMS spreads (second / first, third / first);
* :data:`RADIAL_QUANTILES` quantiles of the distance of its surface samples to their centroid, in RMS radii;
* its mean surface colour (RGB 0..1) times :data:`COLOUR_WEIGHT`: a weak pull, so that among shapes
  alike the same-coloured ones come first, never a gate.

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

RADIAL_QUANTILES = 8
COLOUR_WEIGHT = 0.25


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


def candidate_pairs(features: np.ndarray, *, k: int, hashes: Sequence[Sequence[str | None]] = ()) -> list[tuple[int, int]]:
    """Index pairs (i < j) to compare: each row's ``k`` nearest rows, and rows sharing any hash.

    ``features``: (n, d); ``hashes``: per row, hash strings (content, geometry; None is ignored)."""
    f = np.asarray(features, dtype=np.float64)
    n = len(f)
    pairs: set[tuple[int, int]] = set()
    if n >= 2 and k > 0:
        kk = min(k + 1, n)
        _, idx = cKDTree(f).query(f, k=kk)
        idx = np.asarray(idx).reshape(n, kk)
        for i in range(n):
            for j in idx[i]:
                j = int(j)
                if j != i and j < n:
                    pairs.add((min(i, j), max(i, j)))
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
