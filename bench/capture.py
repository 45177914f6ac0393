"""Capture-sized meshes through ingest and `catalog filter`: time and memory for a few hundred thousand faces.

Usage: .venv/bin/python bench/capture.py [--faces 300000] [--workers 2] [--smoke]
Writes, in a temporary folder, a textured scan-like object (a lumpy, image-textured blob of about
``--faces`` triangles, one GLB), a copy of it turned over and rescaled (another GLB), the same scan
subdivided once more (x4 faces, a "re-tessellated" export) and another source's copy (isotropically
remeshed by pymeshlab to a fifth of the faces, texture re-baked into a new atlas, x0.01, turned), ingests
them into a fresh catalog and runs the filter (shape, mesh-quality and surface-appearance descriptors,
no renders). Prints human lines to stderr and one JSON line to stdout:
{"faces": [...], "ingest_s": ..., "filter_s": ..., "peak_rss_mb": ..., "pairs": [...], "mesh_quality": ...}
The four must come out as one duplicate group (all 6 pairs).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from sqlalchemy import select

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mixcount.catalog.db import open_catalog  # noqa: E402
from mixcount.catalog.ingest import ingest_paths  # noqa: E402
from mixcount.catalog.models import CatalogObject, Flag  # noqa: E402
from mixcount.config import load_config  # noqa: E402
from mixcount.curation.finding.catalog_filter import run_filter  # noqa: E402
from mixcount.demo import library as L  # noqa: E402
from mixcount.demo import traps as T  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", type=int, default=300_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--smoke", action="store_true", help="seconds: a 3,000-face scan (the suite runs it)")
    args = parser.parse_args()
    if args.smoke:
        args.faces = 3_000
    rng = np.random.default_rng(0)
    part = T.scan_like(args.faces, rng)
    with tempfile.TemporaryDirectory(prefix="mixcount-capture-") as tmp:
        root = Path(tmp) / "lib"
        objects = {
            "scan": [part],
            "scan_turned": L.baked([part], L.rotation_xyz((90.0, 0.0, 37.0)), 1.7),
            "scan_retessellated": L.subdivide([part]),
            # another source: isotropically remeshed to a fifth of the faces, texture re-baked, x0.01, turned
            "scan_remeshed_scaled_turned": T.republish([part], method="isotropic", target_faces=len(part.faces) // 5,
                                                       texture_px=2048, rotation=L.rotation_xyz((0.0, 90.0, 120.0)),
                                                       scale=0.01, seed=0),
        }
        for name, parts in objects.items():
            (root / name).mkdir(parents=True)
            (root / name / "model.glb").write_bytes(L.export_glb(parts))
        faces = [int(len(p.faces)) for parts in objects.values() for p in parts]
        print(f"faces: {faces}", file=sys.stderr)
        catalog = open_catalog(str(Path(tmp) / "catalog.db"), data_dir="")
        config = load_config([], [f"ingest.workers={args.workers}"])
        t0 = time.perf_counter()
        summary = ingest_paths(catalog, [root], config=config)
        ingest_s = time.perf_counter() - t0
        print(f"ingest: {summary.as_dict()} in {ingest_s:.1f} s", file=sys.stderr)
        t0 = time.perf_counter()
        result = run_filter(catalog, config)
        filter_s = time.perf_counter() - t0
        with catalog.session() as s:
            names = {o.id: Path(o.model_path).parent.name for o in s.scalars(select(CatalogObject))}
            flags = s.scalars(select(Flag)).all()
        catalog.close()
    pairs = sorted({tuple(sorted((names[f.object_id], names[f.pair_object_id]))) + (f.kind,) for f in flags
                    if f.pair_object_id is not None})
    quality = sorted({(names[f.object_id], f.kind, round(f.score, 3)) for f in flags if f.pair_object_id is None})
    out = {"faces": faces, "ingest_s": round(ingest_s, 2), "filter_s": round(filter_s, 2),
           "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
           "broken": summary.broken, "pairs": pairs, "quality_flags": quality,
           "descriptor_failures": result.descriptor_failures}
    print(json.dumps(out))
    return 0 if summary.broken == 0 and len({p[:2] for p in pairs}) == 6 else 1


if __name__ == "__main__":
    sys.exit(main())
