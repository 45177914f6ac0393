"""Benchmark one composed scene at the paper's settings and print seconds per stage as a JSON line.

    .venv/bin/python bench/compose.py                      # 1024 px, 32 spp, ~100 objects (minutes)
    .venv/bin/python bench/compose.py --resolution 256 --samples 8 --objects 60   # quick look
    .venv/bin/python bench/compose.py --oracle             # also time the paper's one-render-per-object method

The scene comes from a generated demo library (no catalog needed); asset conversion is done before the
clock starts (it is cached per asset in a real run). ``whole_over_rgb`` = whole scene time (stage
writing, worker: import, physics, checks, silhouettes, id passes, RGB; annotation and writing) divided by
the RGB render alone. Target: <= 1.25.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--objects", type=int, default=100)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    ap.add_argument("--oracle", action="store_true", help="also run the one-render-per-object reference")
    ap.add_argument("--work", type=Path, default=None)
    args = ap.parse_args()

    from mixcount.blender.worker import BlenderWorker
    from mixcount.config import load_config
    from mixcount.run.compose import render_threads
    from mixcount.demo.pool import ensure_demo_pool
    from mixcount.run.scene_task import SceneTask, run_scene_task
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-"))
    pool = ensure_demo_pool(work / "demo")
    cfg = load_config([], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}",
                           f"scene.n_objects=[{args.objects},{args.objects}]", f"scene.physics_frames={args.frames}",
                           f"compose.render_threads={args.threads}"])
    spec = sample_scene(args.seed, "train", cfg, pool)
    assets = work / "assets"
    convert_scene_assets(spec, assets)
    threads = render_threads(cfg, workers=1) if args.threads else 0  # 0: Blender's automatic choice
    out = work / "out"
    with BlenderWorker(name="bench", log_dir=work) as worker:
        worker.request({"op": "ping"}, timeout=300)  # start-up is not part of a scene
        outcome = run_scene_task(SceneTask(spec=spec, out_dir=str(out), assets_dir=str(assets), timeout_s=3600,
                                           threads=threads, oracle=args.oracle), worker)
    if outcome.status != "written":
        print(json.dumps({"status": outcome.status, "error": outcome.error}))
        return 1
    meta = json.loads((Path(outcome.path) / "metadata.json").read_text())
    t = meta["timings"]
    stages = {k.split(".", 1)[1]: v for k, v in t.items() if k.startswith("worker.")}
    oracle_s = stages.pop("oracle", None)
    whole = t["total"] - (oracle_s or 0.0)
    rgb = stages["rgb"]
    kept = [o for o in meta["objects"] if o["status"] == "kept"]
    result = {
        "bench": "compose", "resolution": args.resolution, "samples": args.samples, "objects_spawned": spec.n_counted,
        "counted_kept": meta["n_counted"], "distractors_kept": meta["n_distractors"], "dropped": meta["n_dropped"],
        "seconds": {"stage_usd": t["stage"], **stages, "annotate_write": t["annotate"], "whole": round(whole, 3)},
        "whole_over_rgb": round(whole / rgb, 3),
    }
    if oracle_s is not None:
        ious = [o["oracle_iou"] for o in kept if o["oracle_iou"] is not None]
        result["oracle"] = {"seconds": oracle_s, "renders": len(ious), "min_iou": round(min(ious), 5) if ious else None,
                            "mean_iou": round(sum(ious) / len(ious), 5) if ious else None,
                            "paper_method_over_rgb": round((whole + oracle_s - stages["silhouettes"]) / rgb, 3)}
    result["out"] = str(outcome.path)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
