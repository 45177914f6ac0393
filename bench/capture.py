"""Capture-sized meshes through ingest and `catalog filter`: time and memory for a few hundred thousand faces.

Usage: .venv/bin/python bench/capture.py [--faces 300000] [--workers 2]
Writes, in a temporary folder, a textured scan-like object (a lumpy, image-textured blob of about
``--faces`` triangles, one GLB), a copy of it turned over and rescaled (another GLB), and the same scan
subdivided once more (x4 faces, a "re-tessellated" export), ingests them into a fresh catalog and runs the
filter (shape, mesh-quality and surface-appearance descriptors, no renders). Prints human lines to stderr
and one JSON line to stdout:
{"faces": [...], "ingest_s": ..., "filter_s": ..., "peak_rss_mb": ..., "pairs": [...], "mesh_quality": ...}
The copies must come out as one duplicate group.
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
from mixcount.curation.flags import run_filter  # noqa: E402
from mixcount.demo import library as L  # noqa: E402


def scan_like(faces: int, rng: np.random.Generator) -> L.Part:
    """An icosphere with enough subdivisions for ``faces``, pushed into a lumpy potato shape, with a
    striped texture through spherical UVs."""
    import trimesh
    from PIL import Image

    level = max(1, int(round(np.log(faces / 20) / np.log(4))))
    mesh = trimesh.creation.icosphere(subdivisions=level, radius=0.05)
    v = np.asarray(mesh.vertices)
    d = v / np.linalg.norm(v, axis=1, keepdims=True)
    bumps = sum(a * np.sin(k * d @ rng.normal(size=3)) for a, k in ((0.12, 3.0), (0.05, 7.0), (0.02, 15.0)))
    v = v * (1.0 + bumps)[:, None] * np.array([1.6, 1.0, 0.8])
    uv = np.c_[0.5 + np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 0.5 + np.arcsin(d[:, 2].clip(-1, 1)) / np.pi]
    img = Image.fromarray(np.uint8(rng.integers(0, 255, (64, 64, 3)))).resize((256, 256), Image.Resampling.NEAREST)
    return L.Part(v, np.asarray(mesh.faces), uv, image=img, roughness=0.6)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", type=int, default=300_000)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    part = scan_like(args.faces, rng)
    with tempfile.TemporaryDirectory(prefix="mixcount-capture-") as tmp:
        root = Path(tmp) / "lib"
        objects = {
            "scan": [part],
            "scan_turned": L._baked([part], L.rotation_xyz((90.0, 0.0, 37.0)), 1.7),
            "scan_retessellated": L.subdivide([part]),
        }
        for name, parts in objects.items():
            (root / name).mkdir(parents=True)
            (root / name / "model.glb").write_bytes(L.export_glb(parts))
        faces = [int(len(p.faces)) for parts in objects.values() for p in parts]
        print(f"faces: {faces}", file=sys.stderr)
        catalog = open_catalog(str(Path(tmp) / "catalog.db"))
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
    return 0 if summary.broken == 0 and len({p[:2] for p in pairs}) == 3 else 1


if __name__ == "__main__":
    sys.exit(main())
