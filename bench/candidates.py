"""Candidate search of `catalog filter` at the paper's scale: 1,500 and 15,000 objects (descriptor-only).

Usage: .venv/bin/python bench/candidates.py [--sizes 1500 15000] [--k 12] [--align-pairs 20] [--smoke]

Synthetic descriptors stand in for a library: index vectors (:func:`mixcount.curation.finding.candidates.feature`)
and squash queries (:func:`~mixcount.curation.finding.candidates.queries`) of surface samples drawn from random ellipsoids with lumps (one per object, seeded), plus a tenth of the
objects again as turned, squashed copies. For each size: the time to build the k-d index and find every
object's ``k`` nearest (the candidate pairs), the number of pairs against all n(n-1)/2, and the time the
shape alignment (:func:`mixcount.curation.finding.shape_match.match`) would take on those pairs, from the mean of
``--align-pairs`` real alignments (the expensive rule runs on candidates only, after cheap gates that
drop most of them: this is its upper bound). Also the recall of the planted copies among the candidates.
Prints human lines to stderr and one JSON line to stdout:
{"k": 12, "sizes": [{"n", "index_s", "pairs", "all_pairs", "copies_found", "copies", "align_s_per_pair",
"align_upper_bound_s"}], "growth": ...}
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mixcount.curation.finding import shape_match as S  # noqa: E402
from mixcount.curation.finding.candidates import candidate_pairs, queries  # noqa: E402

N_POINTS = 600  # samples per synthetic object for its index vector (the filter uses 6,000: same vector)


def _blob(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    axes = rng.uniform(0.3, 1.0, 3)
    lumps = 1.0 + 0.15 * np.sin(d @ rng.normal(size=3) * 3.0) + 0.08 * np.sin(d @ rng.normal(size=3) * 7.0)
    return d * lumps[:, None] * axes


def _turned(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    s = np.ones(3)
    s[rng.integers(0, 3)] = rng.uniform(0.8, 0.95)
    return (p @ q.T) * s * rng.choice([1.0, 100.0, 39.37])


def library(n: int, seed: int) -> tuple[np.ndarray, list[tuple[int, int]], list[np.ndarray]]:
    """(query vectors (n, 7, d), planted copy pairs, the points of the first objects for alignment timing)."""
    rng = np.random.default_rng(seed)
    n_copies = n // 10
    originals = n - n_copies
    feats, kept = [], []
    for i in range(originals):
        p = _blob(rng, N_POINTS)
        colour = rng.uniform(0, 1, 3)
        feats.append(queries(p, np.tile(colour, (len(p), 1))))
        if i < n_copies:
            kept.append((p, colour))

    copies = []
    for i, (p, colour) in enumerate(kept):
        feats.append(queries(_turned(p, rng), np.tile(colour, (len(p), 1))))
        copies.append((i, originals + i))
    timing = np.random.default_rng(seed + 1)
    points = [_blob(timing, 6000) for _ in range(8)]  # as many samples as the filter's objects have
    return np.asarray(feats), copies, points


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1500, 15000])
    parser.add_argument("--k", type=int, default=12)
    parser.add_argument("--align-pairs", type=int, default=20)
    parser.add_argument("--smoke", action="store_true", help="seconds: 300 and 3,000 objects, 3 alignments")
    args = parser.parse_args()
    if args.smoke:
        args.sizes, args.align_pairs = [300, 3000], 3
    rows = []
    align_s = None
    for n in args.sizes:
        feats, copies, points = library(n, seed=n)
        t0 = time.perf_counter()
        pairs = candidate_pairs(feats[:, 0], k=args.k, extra=feats[:, 1:])
        index_s = time.perf_counter() - t0
        found = len(set(copies) & set(pairs))
        if align_s is None:
            rng = np.random.default_rng(0)
            t1 = time.perf_counter()
            for j in range(args.align_pairs):
                a = S.normalise(points[j % len(points)])
                b = S.normalise(_turned(points[(j + 1) % len(points)], rng))
                S.match(a, b, max_squash=1.34)
            align_s = (time.perf_counter() - t1) / max(args.align_pairs, 1)
        row = {"n": n, "index_s": round(index_s, 3), "pairs": len(pairs), "all_pairs": n * (n - 1) // 2,
               "copies_found": found, "copies": len(copies), "align_s_per_pair": round(align_s, 4),
               "align_upper_bound_s": round(align_s * len(pairs), 1)}
        rows.append(row)
        print(f"{n} objects: index + {args.k} nearest {index_s:.2f} s, {len(pairs)} candidate pairs of "
              f"{row['all_pairs']} ({100 * len(pairs) / row['all_pairs']:.3f} %), planted copies among them "
              f"{found}/{len(copies)}; alignment {align_s:.3f} s a pair -> at most {row['align_upper_bound_s']} s",
              file=sys.stderr)
    growth = None
    if len(rows) >= 2 and rows[0]["index_s"] > 0:
        a, b = rows[0], rows[-1]
        growth = {"n_ratio": b["n"] / a["n"], "index_time_ratio": round(b["index_s"] / a["index_s"], 2),
                  "n_log_n_ratio": round(b["n"] * np.log(b["n"]) / (a["n"] * np.log(a["n"])), 2),
                  "pairs_ratio": round(b["pairs"] / a["pairs"], 2)}
        print(f"growth x{growth['n_ratio']:g} objects: index time x{growth['index_time_ratio']}, n log n "
              f"x{growth['n_log_n_ratio']}, candidate pairs x{growth['pairs_ratio']}", file=sys.stderr)
    print(json.dumps({"k": args.k, "sizes": rows, "growth": growth}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
