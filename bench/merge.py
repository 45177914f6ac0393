"""Merge time and peak memory for N finished scenes fabricated from ONE real composed scene (no rendering).

    .venv/bin/python bench/merge.py --scene OUT/scenes/scene_000003             # N = 1k, 10k, 58k
    .venv/bin/python bench/merge.py --scene DIR --sizes 1000,10000 --keep       # keep the fabricated sets
    .venv/bin/python bench/merge.py                                             # composes a small scene first
    .venv/bin/python bench/merge.py --smoke                                     # seconds: tiny scene, N = 3, 10

Each fabricated scene is the real scene under a new id (``scene_<k:06d>``): ``coco.json`` and
``metadata.json`` rewritten with that id (text replacement; every scene is parsed for real by the merge), ``rgb.png`` hard-linked (the
preview reads it); the other pass files are not needed by the merge and are left out. Every merge runs in
a fresh Python process (``mixcount.dataset.merge.finalize_dataset``), timed, with its peak RSS from
``getrusage``: ``cold`` = the first merge (every metadata.json parsed, index built), ``warm`` = a second
merge with one new scene (a resumed run: the index answers for the rest). Goal: linear, <= 1 GB at 58k.
One line per N on stderr, one JSON line on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MERGE = (
    "import json, resource, sys, time\n"
    "from pathlib import Path\n"
    "from mixcount.dataset.merge import finalize_dataset\n"
    "t = time.perf_counter()\n"
    "finalize_dataset(Path(sys.argv[1]), config={}, config_hash='bench', preview_scenes=16)\n"
    "print(json.dumps({'seconds': round(time.perf_counter() - t, 3),"
    " 'peak_rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}))\n"
)


def fabricate(scene: Path, out: Path, n: int, start: int = 0) -> None:
    """``n`` copies of ``scene`` as scene_<start..start+n-1> under ``out/scenes``."""
    sid = scene.name
    coco = (scene / "coco.json").read_text()
    meta = (scene / "metadata.json").read_text()
    scenes = out / "scenes"
    scenes.mkdir(parents=True, exist_ok=True)
    for k in range(start, start + n):
        new = f"scene_{k:06d}"
        d = scenes / new
        d.mkdir(exist_ok=True)
        (d / "coco.json").write_text(coco.replace(sid, new))
        (d / "metadata.json").write_text(meta.replace(sid, new))  # text as written, new id (seed kept)
        os.link(scene / "rgb.png", d / "rgb.png")


def _merge(out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", MERGE, str(out)], capture_output=True, text=True, env=env,
                         check=True, cwd=ROOT)
    return json.loads(res.stdout.strip().splitlines()[-1])


def _compose_one(work: Path, smoke: bool) -> Path:
    """One real scene (seed 3: ``compose.seed``) of the demo library; ``smoke``: 32 px, 1 sample, 12 objects."""
    from mixcount.config import load_config
    from mixcount.demo.demo_pools import ensure_demo_pool
    from mixcount.run.compose import compose_scenes

    pool = ensure_demo_pool(work / "demo")
    sets = (["compose.resolution=32", "compose.samples=1", "scene.n_objects=[12,12]", "scene.physics_frames=60"]
            if smoke else ["compose.resolution=256", "compose.samples=4", "scene.n_objects=[54,54]",
                           "scene.physics_frames=120"])
    cfg = load_config([], [*sets, "compose.seed=3"])
    compose_scenes(pool=pool, config=cfg, out_dir=work / "one", assets_dir=work / "assets", n=1, progress=False)
    return next(d for d in (work / "one" / "scenes").iterdir() if not d.name.startswith("."))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=None, help="a finished scene folder (default: compose one)")
    ap.add_argument("--sizes", default="1000,10000,58000")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--keep", action="store_true", help="keep the fabricated datasets")
    ap.add_argument("--smoke", action="store_true", help="seconds: a 32-px scene, N = 3 and 10 (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:
        args.sizes = "3,10"
    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-merge-"))
    scene = args.scene or _compose_one(work, args.smoke)
    meta = json.loads((scene / "metadata.json").read_text())
    rows = []
    for n in [int(s) for s in args.sizes.split(",") if s.strip()]:
        out = work / f"merge_{n}"
        if out.exists():
            shutil.rmtree(out)
        t = time.perf_counter()
        fabricate(scene, out, n)
        fab_s = time.perf_counter() - t
        cold = _merge(out)
        fabricate(scene, out, 1, start=n)  # a resumed run added one scene
        warm = _merge(out)
        coco_mb = sum(p.stat().st_size for p in (out / "annotations").glob("instances_*.json")) / 1e6
        row = {"scenes": n, "fabricate_s": round(fab_s, 1), "cold": cold, "warm_plus_one": warm,
               "merged_coco_mb": round(coco_mb, 1), "us_per_scene_cold": round(1e6 * cold["seconds"] / n, 1)}
        rows.append(row)
        print(f"N={n:6d}  cold {cold['seconds']:8.2f} s  {cold['peak_rss_mb']:7.1f} MB peak   warm(+1) "
              f"{warm['seconds']:8.2f} s  {warm['peak_rss_mb']:7.1f} MB   merged COCO {coco_mb:.0f} MB", file=sys.stderr)
        if not args.keep:
            shutil.rmtree(out)
    print(json.dumps({"bench": "merge", "source_scene": str(scene), "objects_per_scene": len(meta["objects"]),
                      "annotations_per_scene": len(json.loads((scene / "coco.json").read_text())["annotations"]),
                      "resolution": meta["image"]["width"], "cpu_count": os.cpu_count(), "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
