"""Visibility-filter seconds for scenes of 30, 100 and 200 objects, next to the RGB render of the same scene.

    .venv/bin/python bench/visibility.py                          # 1024 px, 32 spp, 30/100/200 objects
    .venv/bin/python bench/visibility.py --samples 8 --sizes 30,100   # quicker
    .venv/bin/python bench/visibility.py --pools heavy               # only the capture-like pool

The visibility filter is everything the worker does to decide which objects are visible enough:
``frame_check`` (origins inside the frame), ``silhouettes`` (unoccluded masks from the numpy rasteriser),
``id_pass`` (the 1-sample object-index renders, every round) and ``visibility`` (the ratios). Its share of
the whole scene (stage writing + worker + annotation) is ``filter_over_scene``; target <= 0.10 at every
size, growing far slower than the object count. Scenes come from the light demo library and its
capture-like heavy copy (>= 200k faces per object, bench/pools.py), both with collision proxies, printed
side by side with the physics share (physics / scene); asset conversion, proxies and the bpy start-up
happen before the clock starts (all one-off in a real run).
Prints one line per size on stderr and one JSON line at the end on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

VISIBILITY_STAGES = ("frame_check", "silhouettes", "id_pass", "visibility")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="30,100,200", help="objects per scene, comma-separated")
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--pools", default="light,heavy", help="light, heavy or both")
    ap.add_argument("--smoke", action="store_true", help="seconds: tiny sizes, same code path (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:  # one 12-object scene of the light pool at 32 px, 1 sample, 60 frames
        args.sizes, args.resolution, args.samples, args.frames, args.threads, args.pools = "12", 32, 1, 60, 1, "light"
    sys.path.insert(0, str(ROOT / "bench"))
    from pools import load_pool, run_fresh_scene, warm_mesh_cache, with_proxies

    from mixcount.config import load_config
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets
    from mixcount.worker.client import BlenderWorker

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-vis-"))
    threads = args.threads or os.cpu_count() or 1
    rows = []
    jobs = [(p.strip(), int(s)) for p in args.pools.split(",") if p.strip()
            for s in args.sizes.split(",") if s.strip()]
    with BlenderWorker(name="bench-vis", log_dir=work) as worker:
        worker.request({"op": "ping"}, timeout=300)
        for pool_name, n in jobs:
            pool = load_pool(pool_name, work)
            cfg = load_config([], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}",
                                   f"scene.n_objects=[{n},{n}]", f"scene.physics_frames={args.frames}",
                                   f"compose.render_threads={threads}"])
            spec = with_proxies(sample_scene(args.seed, "train", cfg, pool),
                                work / "proxies", cfg.ingest.proxy_max_vertices)
            assets = work / "assets"
            warm_mesh_cache(worker, convert_scene_assets(spec, assets), cfg.compose.mesh_cache)  # before the clock
            out = work / f"out_{pool_name}_{n}_{args.resolution}px_{args.samples}spp"
            outcome, meta, stages = run_fresh_scene(worker, spec, out, assets, timeout_s=3600, threads=threads,
                                                    mesh_cache=cfg.compose.mesh_cache)
            if meta is None:
                rows.append({"pool": pool_name, "objects": n, "status": outcome.status, "error": outcome.error})
                print(json.dumps(rows[-1]), file=sys.stderr)
                continue
            t = meta["timings"]
            vis = sum(stages.get(k, 0.0) for k in VISIBILITY_STAGES)
            whole = t["total"]
            row = {"pool": pool_name, "objects": n, "spawned_counted": spec.n_counted, "counted_kept": meta["n_counted"],
                   "distractors_kept": meta["n_distractors"], "dropped": meta["n_dropped"],
                   "filter_s": round(vis, 3), **{f"{k}_s": stages.get(k) for k in VISIBILITY_STAGES},
                   "rgb_s": stages.get("rgb"), "physics_s": stages.get("physics"), "scene_s": round(whole, 3),
                   "filter_over_scene": round(vis / whole, 4), "filter_over_rgb": round(vis / stages["rgb"], 4),
                   "physics_share": round(stages.get("physics", 0.0) / whole, 4)}
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
    ok = [r for r in rows if "filter_s" in r]
    by = {(r["pool"], r["objects"]): r for r in ok}
    pools = list(dict.fromkeys(p for p, _ in jobs))
    print("objects | " + " | ".join(f"{p}: filter s, filter %, physics s, physics %, rgb s" for p in pools),
          file=sys.stderr)
    for n in dict.fromkeys(n for _, n in jobs):
        cells = [("-" if (r := by.get((p, n))) is None else
                  f"{r['filter_s']:.2f}, {100 * r['filter_over_scene']:.1f} %, {r['physics_s']:.2f}, "
                  f"{100 * r['physics_share']:.1f} %, {r['rgb_s']:.2f}") for p in pools]
        print(f"{n:7d} | " + " | ".join(cells), file=sys.stderr)
    result = {"bench": "visibility", "resolution": args.resolution, "samples": args.samples, "threads": threads,
              "cpu_count": os.cpu_count(), "scenes": rows,
              "max_filter_over_scene": max((r["filter_over_scene"] for r in ok), default=None),
              "target_met": bool(ok) and len(ok) == len(rows) and all(r["filter_over_scene"] <= 0.10 for r in ok)}
    if len(ok) >= 2 and ok[0]["pool"] == ok[-1]["pool"]:
        a, b = ok[0], ok[-1]
        result["growth"] = {"objects_ratio": round(b["objects"] / a["objects"], 2),
                            "filter_ratio": round(b["filter_s"] / max(a["filter_s"], 1e-9), 2)}
    print(json.dumps(result))
    return 0 if args.smoke or result["target_met"] else 1  # a smoke scene is too small for the target


if __name__ == "__main__":
    sys.exit(main())
