"""Scenes per hour and core-seconds per scene at quick settings: local executor vs Ray on a local cluster;
with ``--paper``, scenes per hour and core-minutes per scene at the paper's settings on the heavy pool.

    .venv/bin/python bench/throughput.py                       # 8 scenes, 2 workers, configs/quick.toml
    .venv/bin/python bench/throughput.py --scenes 4 --resolution 96 --samples 2   # quicker
    .venv/bin/python bench/throughput.py --memory 40 --resolution 64 --samples 1  # worker RSS per scene
    .venv/bin/python bench/throughput.py --paper --scenes 3     # 1024 px, 32 spp, default scene config
                                                                # (30-200 objects), heavy pool, proxies
    .venv/bin/python bench/throughput.py --paper --scenes 3 --set compose.denoise_prefilter=FAST
    .venv/bin/python bench/throughput.py --paper --scenes 4 --set compose.settle_ahead=false  # settle in the render worker

``--paper``: one local worker using every core (``--workers`` slots share them), default config (not
quick), the capture-like heavy pool (bench/pools.py) with collision proxies; ``core_min_per_scene`` =
cores x wall / scenes, next to the paper's 2 min per scene on 12 cores (about 24 core-minutes). Asset
conversion and the worker's .blend mesh cache of each asset are made before the clock (once per asset
in a real run; ``--cold-mesh-cache`` leaves the cache to the scenes).

Both executors compose the SAME seeds (scene_000000 ...) from a generated demo library into separate
folders, with the same number of slots (``--workers``, one CPU each). Asset conversion is done before the
clock starts (it is cached per asset in a real run); the bpy worker start-up is inside the clock for both
(once per slot), the Ray cluster start-up is reported apart (``ray_startup_s``: a real cluster is already
running). ``core_s_per_scene`` = slots x wall seconds / scenes (the cores the run held), and
``cpu_s_per_scene`` = CPU seconds the bpy workers really used per scene (from /proc at the end of the
run; the driver's and Ray's own CPU are not in it), ``worker_rss_mb`` their resident memory then. ``annotations_equal`` checks the two runs wrote the same COCO annotations. One JSON line at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

TICK = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: Optional[int]) -> float:
    """utime + stime of ``pid`` in seconds (0 when gone)."""
    if not pid:
        return 0.0
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / TICK
    except (OSError, IndexError, ValueError):
        return 0.0


def _rss_mb(pid: Optional[int]) -> Optional[float]:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024, 1)
    except (OSError, ValueError, TypeError):
        return None
    return None


def _annotations(out: Path, split: str) -> list[tuple[Any, ...]]:
    doc = json.loads((out / "annotations" / f"instances_{split}.json").read_text())
    scene_of = {im["id"]: im["scene_id"] for im in doc["images"]}
    return sorted((scene_of[a["image_id"]], a["category_id"], tuple(a["bbox"]), a["area"], a["segmentation"]["counts"],
                   a["is_distractor"]) for a in doc["annotations"])


def _worker_pids(worker: Any) -> list[Any]:
    """The worker's processes: the render worker, and the companion that settles ahead when it has one."""
    settler = getattr(worker, "settler", None)
    return [worker.pid] + ([settler.pid] if settler is not None else [])


def _run(kind: str, executor: Any, *, pool: list[Any], cfg: Any, out: Path, assets: Path, n: int,
         pids: Any) -> dict[str, Any]:
    from mixcount.run.compose import compose_scenes

    t0 = time.perf_counter()
    summary = compose_scenes(pool=pool, config=cfg, out_dir=out, assets_dir=assets, n=n, executor=executor,
                             progress=False)
    wall = time.perf_counter() - t0
    live = [p for p in pids() if p]  # the workers are still up (idle) until the executor closes
    cpu = [_cpu_s(p) for p in live]
    rss = [r for r in (_rss_mb(p) for p in live) if r]
    slots = executor.slots
    scenes = max(1, summary.written)
    return {"executor": kind, "slots": slots, "written": summary.written, "failed": summary.failed,
            "regenerated": summary.empty + summary.rejected, "wall_s": round(wall, 2),
            "scenes_per_hour": round(3600 * summary.written / wall, 1),
            "core_s_per_scene": round(slots * wall / scenes, 2),
            "cpu_s_per_scene": round(sum(cpu) / scenes, 2) if cpu else None,
            "worker_rss_mb": rss}


def _memory(args: Any, *, pool: list[Any], cfg: Any, assets: Path, work: Path) -> dict[str, Any]:
    """RSS of one local bpy worker after each of ``args.memory`` scenes, recycling off and on."""
    from mixcount.run.compose import compose_scenes
    from mixcount.run.local import LocalExecutor

    series: dict[str, Any] = {}
    for label, k in (("no_recycle", 0), (f"recycle_after_{args.recycle_after}", args.recycle_after)):
        ex = LocalExecutor(1, log_dir=work / "logs", recycle_after=k, settle_ahead=False)
        rss: list[Optional[float]] = []
        try:
            t0 = time.perf_counter()
            summary = compose_scenes(pool=pool, config=cfg, out_dir=work / f"mem_{label}", assets_dir=assets,
                                     n=args.memory, executor=ex, progress=False,
                                     on_outcome=lambda _o, rss=rss, ex=ex: rss.append(_rss_mb(ex.workers[0].pid)))
            wall = time.perf_counter() - t0
        finally:
            ex.close()
        vals = [r for r in rss if r]
        series[label] = {"written": summary.written, "wall_s": round(wall, 1), "rss_mb_after_each": rss,
                         "first": vals[0] if vals else None, "max": max(vals) if vals else None,
                         "last": vals[-1] if vals else None}
    return {"bench": "throughput-memory", "scenes": args.memory, "resolution": args.resolution,
            "samples": args.samples, **series}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--only", choices=("local", "ray"), default=None)
    ap.add_argument("--memory", type=int, default=0, metavar="N",
                    help="instead: N scenes on ONE local worker, its RSS after every scene, without and with "
                         "recycling (--recycle-after)")
    ap.add_argument("--recycle-after", type=int, default=10)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--paper", action="store_true", help="paper settings on the heavy pool (see above)")
    ap.add_argument("--cold-mesh-cache", action="store_true",
                    help="--paper: leave the .blend mesh cache for the scenes to make (first use of each asset)")
    ap.add_argument("--pool", choices=("light", "heavy"), default=None, help="--paper pool (default heavy)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="--paper: extra config override (repeatable), e.g. --set compose.denoise_prefilter=FAST")
    ap.add_argument("--smoke", action="store_true", help="seconds: 2 local scenes at 32 px, 1 sample (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:  # local executor only: the suite's Ray tests start their own cluster
        args.scenes, args.workers, args.resolution, args.samples, args.only = 2, 1, 32, 1, "local"
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a private 127.0.0.1 cluster
    if args.paper:
        return _paper(args)

    from mixcount.config import load_config
    from mixcount.demo.demo_pools import ensure_demo_pool
    from mixcount.run.factory import make_executor
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-tp-"))
    pool = ensure_demo_pool(work / "demo")
    cfg = load_config(["quick"], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}",
                                  "compose.render_threads=1", "compose.ray_cpus_per_worker=1"])
    assets = work / "assets"
    for s in range(cfg.compose.seed, cfg.compose.seed + 3 * args.scenes + 4):
        convert_scene_assets(sample_scene(s, "train", cfg, pool), assets)  # warm the asset cache

    if args.memory:
        print(json.dumps(_memory(args, pool=pool, cfg=cfg, assets=assets, work=work)))
        return 0
    runs = []
    if args.only in (None, "local"):
        ex = make_executor("local", args.workers, config=cfg.compose, log_dir=work / "logs")
        try:
            runs.append(_run("local", ex, pool=pool, cfg=cfg, out=work / "local", assets=assets, n=args.scenes,
                             pids=lambda: [p for w in ex.workers for p in _worker_pids(w)]))
        finally:
            ex.close()
    if args.only in (None, "ray"):
        t = time.perf_counter()
        ex = make_executor("ray", args.workers, config=cfg.compose, log_dir=work / "logs")
        startup = time.perf_counter() - t
        try:
            runs.append({**_run("ray", ex, pool=pool, cfg=cfg, out=work / "ray", assets=assets, n=args.scenes,
                                pids=lambda: [i.get("worker_pid") for i in ex.info()]),
                         "ray_startup_s": round(startup, 2)})
        finally:
            ex.close()
    result: dict[str, Any] = {"bench": "throughput", "scenes": args.scenes, "workers": args.workers,
                              "resolution": args.resolution, "samples": args.samples, "cpu_count": os.cpu_count(),
                              "runs": runs}
    if len(runs) == 2:
        result["annotations_equal"] = _annotations(work / "local", "train") == _annotations(work / "ray", "train")
        result["ray_over_local_wall"] = round(runs[1]["wall_s"] / runs[0]["wall_s"], 3)
    print(json.dumps(result))
    return 0


PAPER_CORE_MIN = 24.0  # MixCount: about 2 minutes per scene on 12 CPU cores


def _paper(args: Any) -> int:
    """Scenes per hour and core-minutes per scene at paper settings on the heavy pool."""
    import sys as _sys

    _sys.path.insert(0, str(ROOT / "bench"))
    from pools import load_pool, warm_mesh_cache, with_ingest_meshes

    from mixcount.config import load_config
    from mixcount.run.local import LocalExecutor
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets

    argv = " ".join(_sys.argv)
    resolution = args.resolution if "--resolution" in argv else 1024
    samples = args.samples if "--samples" in argv else 32
    workers = args.workers if "--workers" in argv else 1
    cores = os.cpu_count() or 1
    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-paper-"))
    pool_name = args.pool or "heavy"
    cfg = load_config([], [f"compose.resolution={resolution}", f"compose.samples={samples}",
                           f"compose.render_threads={max(1, cores // workers)}", "compose.scene_timeout_s=14400",
                           *args.set])
    pool = load_pool(pool_name, work)
    budget = cfg.ingest.proxy_max_vertices
    sconf = cfg
    used: set[int] = set()
    for s in range(cfg.compose.seed, cfg.compose.seed + 2 * args.scenes + 2):  # only the objects scenes use
        used |= {a.object_id for a in sample_scene(s, "train", sconf, pool).assets}
    pool = [with_ingest_meshes(o, o.container, work / "proxies", budget, cfg.ingest.collision_face_budget)
            if o.object_id in used else o for o in pool]
    t = time.perf_counter()
    converted = {}
    for s in range(cfg.compose.seed, cfg.compose.seed + 2 * args.scenes + 2):  # warm the asset cache
        converted.update(convert_scene_assets(sample_scene(s, "train", sconf, pool), work / "assets"))
    prep = time.perf_counter() - t
    import shutil

    shutil.rmtree(work / "paper", ignore_errors=True)  # a fresh run (a finished scene would be skipped)
    ex = LocalExecutor(workers, log_dir=work / "logs", recycle_after=0, settle_ahead=cfg.compose.settle_ahead)
    try:
        for w in ex.workers:
            w.request({"op": "ping"}, timeout=300)  # bpy start-up is once per worker, not per scene
            if getattr(w, "settler", None) is not None:
                w.settler.start()  # ... and so is the settle-ahead companion's
        t = time.perf_counter()
        if not args.cold_mesh_cache:  # each asset's .blend, made once per dataset like its conversion
            warm_mesh_cache(ex.workers[0], converted, cfg.compose.mesh_cache)
        prep += time.perf_counter() - t
        run = _run("local", ex, pool=pool, cfg=cfg, out=work / "paper", assets=work / "assets", n=args.scenes,
                   pids=lambda: [p for w in ex.workers for p in _worker_pids(w)])
    finally:
        ex.close()
    scenes = max(1, run["written"])
    wall = run["wall_s"]
    metas = [json.loads(p.read_text()) for p in sorted((work / "paper" / "scenes").glob("scene_*/metadata.json"))]
    phys = [m["timings"].get("worker.physics", 0.0) for m in metas]
    rgb = [m["timings"].get("worker.rgb", 0.0) for m in metas]
    total = [m["timings"].get("total", 0.0) for m in metas]
    result = {
        "bench": "throughput-paper", "pool": pool_name, "resolution": resolution, "samples": samples,
        "scenes": run["written"], "workers": workers, "cores": cores, "wall_s": wall,
        "scenes_per_hour": round(3600 * run["written"] / wall, 2),
        "core_min_per_scene": round(cores * wall / scenes / 60, 2),
        "cpu_min_per_scene": round(run["cpu_s_per_scene"] / 60, 2) if run["cpu_s_per_scene"] else None,
        "paper_core_min_per_scene": PAPER_CORE_MIN,
        "objects_per_scene": [len(m["objects"]) for m in metas],
        "counted_kept_per_scene": [m["n_counted"] for m in metas], "set": args.set,
        "physics_share": round(sum(phys) / max(sum(total), 1e-9), 4),
        "whole_over_rgb": round(sum(total) / max(sum(rgb), 1e-9), 3),
        "asset_prep_s": round(prep, 1), "cold_mesh_cache": bool(args.cold_mesh_cache), "failed": run["failed"], "regenerated": run["regenerated"],
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
