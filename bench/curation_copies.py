"""The real-capture copy pool (tests/capture_copies.py, issue 57): recall per kind of copy and precision of the
pair rules, the tuning part and the held-back part reported apart.

Usage: .venv/bin/python bench/curation_copies.py [--parts tuning held_out] [--set filter.size_rescale=1e9] [--smoke]

Each part is its originals (real models of pybullet, genesis-world, metaworld, glmark2-data, assimp-testmodels,
prusa-slicer), each copied six ways (another print, another resolution, a squash, other units, another
pose, re-indexed), plus the look-alikes of one kind (mugs, cups, bowls, bottles, a bolt and a nut). The
pair rules run as `catalog filter` runs them (candidate index, then the rules) on each part alone.
Prints a table per part to stderr and one JSON line to stdout: {part: evaluate(...)} (see
:func:`capture_copies.evaluate`). Skips a part, saying why, when a package cannot be had. ``--set`` overrides
a setting as the CLI's does (``filter.size_rescale=1e9``: the size evidence off). ``--smoke``: pybullet's duck
with its six copies and pybullet's mug, the tuning part only (a few seconds; tests/test_benches.py)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "tests")]
SMOKE = {"duck_pybullet", "mug_pybullet"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="+", default=["tuning", "held_out"], choices=["tuning", "held_out"])
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="override a setting")
    ap.add_argument("--smoke", action="store_true", help="one original with its copies and one look-alike")
    args = ap.parse_args()
    from capture_copies import evaluate, pool

    from mixcount.config import load_config

    th = load_config(overrides=args.set).filter
    out = {}
    for part in ["tuning"] if args.smoke else args.parts:
        t0 = time.perf_counter()
        entries, why = pool((part,), only=SMOKE, demo_look_alikes=False) if args.smoke else pool((part,))
        if entries is None:
            print(f"{part}: skipped: {why}", file=sys.stderr)
            continue
        got = evaluate(entries, th)
        got["seconds"] = round(time.perf_counter() - t0, 1)
        out[part] = got
        print(f"\n{part}: {got['objects']} objects, {got['candidate_pairs']} candidate pairs, {got['seconds']} s", file=sys.stderr)
        print(f"{'kind':<12}{'copies':>8}{'candidates':>12}{'paired':>8}", file=sys.stderr)
        for kind, row in got["per_kind"].get(part, {}).items():
            print(f"{kind:<12}{row['copies']:>8}{row['candidates']:>12}{row['paired']:>8}", file=sys.stderr)
        print(f"missed: {got['missed']}", file=sys.stderr)
        print(f"decide pairs {got['decide_pairs']}, of one object {got['decide_same_object']}, precision "
              f"{got['precision']}; between different objects: {got['false_pairs']}; duplicates between "
              f"different objects: {got['false_duplicates']}", file=sys.stderr)
    print(json.dumps(out, sort_keys=True))


if __name__ == "__main__":
    main()
