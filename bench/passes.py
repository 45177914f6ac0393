"""Bytes and precision of every depth / normal format on a real rendered scene.

    .venv/bin/python bench/passes.py --scene OUT/scenes/scene_000003   # a scene written with the npy formats
    .venv/bin/python bench/passes.py --resolution 1024 --samples 32    # composes one (npy formats) first
    .venv/bin/python bench/passes.py --smoke                           # seconds: a 32-px scene

Reads the exact float32 passes (``depth.npy``, ``normal.npy``; compose with ``compose.depth_format="npy"``
and ``compose.normal_format="npy"``), writes them in every format of :mod:`mixcount.annotate.passes`,
reads them back with ``read_depth`` / ``read_normals`` and prints bytes, max / mean depth error (metres
and relative) and max / mean angular normal error (degrees, over surface pixels). One JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _compose_npy(work: Path, resolution: int, samples: int, objects: int, extra: list[str]) -> Path:
    """One real scene (seed 3) written with the exact float32 passes; ``extra``: more config overrides."""
    from mixcount.config import load_config
    from mixcount.demo.demo_pools import ensure_demo_pool
    from mixcount.run.compose import compose_scenes

    pool = ensure_demo_pool(work / "demo")
    cfg = load_config([], [f"compose.resolution={resolution}", f"compose.samples={samples}",
                           f"scene.n_objects=[{objects},{objects}]", "compose.depth_format='npy'",
                           "compose.normal_format='npy'", "compose.seed=3", *extra])
    compose_scenes(pool=pool, config=cfg, out_dir=work / "npy", assets_dir=work / "assets", n=1, progress=False)
    return next(d for d in (work / "npy" / "scenes").iterdir() if not d.name.startswith("."))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=None)
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--objects", type=int, default=100)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--smoke", action="store_true", help="seconds: a 32-px, 1-sample, 12-object scene (the suite runs it)")
    args = ap.parse_args()
    extra: list[str] = []
    if args.smoke:
        args.resolution, args.samples, args.objects = 32, 1, 12
        extra = ["scene.physics_frames=60"]

    from mixcount.annotate.passes import (
        DEPTH_FORMATS,
        NORMAL_FORMATS,
        read_depth,
        read_normals,
        write_depth,
        write_normals,
    )

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-passes-"))
    scene = args.scene or _compose_npy(work, args.resolution, args.samples, args.objects, extra)
    depth = np.load(scene / "depth.npy")
    normals = np.load(scene / "normal.npy")
    surf = depth > 0
    out: dict = {"bench": "passes", "scene": str(scene), "shape": list(depth.shape),
                 "surface_fraction": round(float(surf.mean()), 4), "depth_range_m": [float(depth[surf].min()),
                                                                                    float(depth.max())],
                 "depth": {}, "normal": {}}
    for fmt in DEPTH_FORMATS:
        d = work / f"depth_{fmt}"
        d.mkdir(exist_ok=True)
        rec = write_depth(d, depth, fmt)
        back = read_depth(d / rec["file"])
        err = np.abs(back.astype(np.float64) - depth)[surf]
        out["depth"][fmt] = {"bytes": (d / rec["file"]).stat().st_size, "max_err_m": float(err.max()),
                             "mean_err_m": float(err.mean()),
                             "max_rel_err": float((err / depth[surf]).max()),
                             "surface_mask_kept": bool(((back > 0) == surf).all()), **{k: v for k, v in rec.items()
                                                                                       if k == "unit_m"}}
    nsurf = np.any(normals != 0, axis=-1)
    for fmt in NORMAL_FORMATS:
        d = work / f"normal_{fmt}"
        d.mkdir(exist_ok=True)
        rec = write_normals(d, normals, fmt)
        back = read_normals(d / rec["file"]).astype(np.float64)
        a, b = back[nsurf], normals[nsurf].astype(np.float64)
        b = b / np.linalg.norm(b, axis=1, keepdims=True)
        ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), (a * b).sum(1)))
        out["normal"][fmt] = {"bytes": (d / rec["file"]).stat().st_size, "max_err_deg": float(ang.max()),
                              "mean_err_deg": float(ang.mean()),
                              "surface_mask_kept": bool((np.any(back != 0, axis=-1) == nsurf).all())}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
