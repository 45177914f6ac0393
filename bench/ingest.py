"""Ingest throughput: first ingest vs unchanged rerun of ~200 generated objects.

Usage: .venv/bin/python bench/ingest.py [--objects 200] [--workers 2] [--subdivide 2] [--smoke]
Prints human lines to stderr and one JSON line to stdout at the end:
{"objects": N, "first_s": ..., "first_obj_per_s": ..., "rerun_s": ..., "rerun_obj_per_s": ..., "ratio": ...}
The rerun only hashes files and compares with the catalog (no mesh work), so the ratio should be >= 10.

The demo library's meshes are deliberately light (~100-2,500 faces); real captures have 10^4-10^6.
``--subdivide K`` (default 2: x16 faces, ~20k for a ball) makes the bench set capture-like by
subdividing every part K times (UVs and textures kept); ``--subdivide 0`` measures the demo meshes as
generated. Both figures are honest measurements; they answer different questions.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mixcount.catalog.db import open_catalog  # noqa: E402
from mixcount.catalog.ingest import ingest_paths  # noqa: E402
from mixcount.config import load_config  # noqa: E402
from mixcount.demo.library import generate_demo_library  # noqa: E402


def densify(lib: Path, times: int) -> None:
    """Subdivide every part of every readable GLB in ``lib`` ``times`` times (capture-like density)."""
    import trimesh

    for glb in sorted(lib.glob("*/3d-asset.glb")):
        try:
            scene = trimesh.load(glb, force="scene")
        except Exception:
            continue  # the planted broken files stay broken
        for key, geom in list(scene.geometry.items()):
            for _ in range(times):
                geom = geom.subdivide()
            scene.geometry[key] = geom
        glb.write_bytes(scene.export(file_type="glb"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=200, help="about this many objects (whole demo libraries of 79)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--subdivide", type=int, default=2, help="subdivide every part K times (x4^K faces)")
    parser.add_argument("--smoke", action="store_true",
                        help="seconds: one demo library as generated; exit 0 whatever the ratio (the suite runs it)")
    args = parser.parse_args()
    if args.smoke:
        args.objects, args.subdivide = 1, 0
    config = load_config(values={"ingest.workers": args.workers})
    with tempfile.TemporaryDirectory(prefix="mixcount-bench-") as tmp:
        root = Path(tmp)
        libs, total, seed = [], 0, 0
        t0 = time.perf_counter()
        while total < args.objects:
            lib = root / f"lib{seed}"
            truth = generate_demo_library(lib, seed=100 + seed)
            if args.subdivide:
                densify(lib, args.subdivide)
            libs.append(lib)
            total += truth["expected"]["total"]
            seed += 1
        gen_s = time.perf_counter() - t0
        print(f"generated {total} objects in {len(libs)} libraries in {gen_s:.1f} s", file=sys.stderr)
        catalog = open_catalog(str(root / "bench.db"), data_dir="")
        try:
            t0 = time.perf_counter()
            first = ingest_paths(catalog, libs, config=config)
            first_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            rerun = ingest_paths(catalog, libs, config=config)
            rerun_s = time.perf_counter() - t0
        finally:
            catalog.close()
    assert rerun.new == rerun.updated == 0 and rerun.unchanged == first.new, rerun.as_dict()
    result = {
        "objects": first.total, "workers": args.workers, "subdivide": args.subdivide, "new": first.new, "broken": first.broken,
        "first_s": round(first_s, 3), "first_obj_per_s": round(first.total / first_s, 1),
        "rerun_s": round(rerun_s, 3), "rerun_obj_per_s": round(rerun.total / rerun_s, 1),
        "ratio": round(first_s / rerun_s, 1),
    }
    print(f"first ingest: {result['first_obj_per_s']} objects/s; unchanged rerun: {result['rerun_obj_per_s']} "
          f"objects/s; {result['ratio']}x", file=sys.stderr)
    print(json.dumps(result))
    return 0 if args.smoke or result["ratio"] >= 10 else 1


if __name__ == "__main__":
    sys.exit(main())
