"""Benchmark composed scenes per pool and size: seconds per stage, physics share, whole / RGB, bytes.

    .venv/bin/python bench/compose.py                                   # paper settings: 1024 px, 32 spp,
                                                                        # light + heavy pool, 30/100/200 objects
    .venv/bin/python bench/compose.py --resolution 256 --samples 8 --sizes 30 --pools heavy   # quick look
    .venv/bin/python bench/compose.py --no-proxies                      # collide through full-mesh hulls
    .venv/bin/python bench/compose.py --oracle                          # also the one-render-per-object method
    .venv/bin/python bench/compose.py --settle-ahead --sizes 200 --pools heavy --seed 1   # settle beside the render
    .venv/bin/python bench/compose.py --smoke                           # seconds: one tiny scene (the suite)

Pools (bench/pools.py): ``light`` = the generated demo library; ``heavy`` = the same objects subdivided to
>= 200k faces, textures kept (a real capture's size). Asset conversion, proxy building and the bpy start-up
happen before the clock starts (all cached or one-off in a real run), and so does the worker's .blend cache
of each asset's imported mesh (``compose.mesh_cache``; ``--cold-mesh-cache`` leaves it for the scene's
import to make, the cost of an asset's first scene). Per scene: ``whole`` = stage writing
+ worker (import, physics, checks, silhouettes, id passes, passes, RGB) + annotation and writing;
``whole_over_rgb`` = whole / RGB render (target <= 1.15 on the heavy pool at paper settings);
``physics_share`` = physics / whole (target <= 0.05); ``bytes`` = the finished scene folder (target
<= 4 MB at 1024 px). A side-by-side table goes to stderr, one JSON line to stdout.

``--settle-ahead`` measures ``compose.settle_ahead`` (a companion bpy process settles the next scene while
the current one renders) in its steady state: each scene is run three times in a row through a
:class:`~mixcount.worker.settle_ahead.SettleAheadWorker`, copy k + 1 settling in the companion while copy k
renders, and the middle copy is reported. Its ``whole`` is the wall time from the end of copy 0 to the
end of copy 1 (stage writing excluded: the look-ahead does it during the previous render), its RGB the
render that ran beside copy 2's settle. ``same_poses`` says copy 1 (settled in the companion) kept the
same objects at the same poses as copy 0 (settled in the render worker).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--sizes", default="30,100,200", help="objects per scene, comma-separated")
    ap.add_argument("--objects", type=int, default=None, help="one size only (same as --sizes N)")
    ap.add_argument("--pools", default="light,heavy", help="light, heavy or both")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    ap.add_argument("--min-faces", type=int, default=200_000, help="faces per object of the heavy pool")
    ap.add_argument("--no-proxies", action="store_true", help="collide through the full meshes' hulls")
    ap.add_argument("--oracle", action="store_true", help="also run the one-render-per-object reference")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra config override (repeatable), e.g. --set scene.physics_substeps=2")
    ap.add_argument("--cold-mesh-cache", action="store_true",
                    help="do not make the .blend mesh cache before the clock (each asset's first scene)")
    ap.add_argument("--no-warmup", action="store_true",
                    help="measure the worker's first scene cold (by default a 64 px, 1 spp scene runs first, "
                         "outside the clock: Cycles' and OIDN's one-off start-up in a worker)")
    ap.add_argument("--settle-ahead", action="store_true",
                    help="settle each scene in a companion process during the previous render (3 copies, "
                         "the middle one measured)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--smoke", action="store_true", help="seconds: tiny sizes, same code path (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:  # one 12-object scene of the light pool at 32 px, 1 sample, 60 frames, no warm-up
        args.resolution, args.samples, args.sizes, args.objects, args.pools = 32, 1, "12", None, "light"
        args.frames, args.threads, args.no_warmup = 60, 1, True

    from pools import load_pool, run_fresh_scene, scene_bytes, warm_mesh_cache, with_proxies

    from mixcount.config import load_config
    from mixcount.engine import mesh_cache
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets
    from mixcount.worker.client import BlenderWorker
    from mixcount.worker.settle_ahead import SettleAheadWorker

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-"))
    sizes = [args.objects] if args.objects else [int(s) for s in args.sizes.split(",") if s.strip()]
    pools = [p.strip() for p in args.pools.split(",") if p.strip()]
    threads = args.threads or os.cpu_count() or 1
    rows = []

    def staged(cfg: Any, pool: Any) -> tuple[Any, dict]:
        """The bench's scene for ``cfg``: sampled at --seed, proxies attached, its assets converted."""
        spec = sample_scene(args.seed, "train", cfg, pool)
        if not args.no_proxies:
            spec = with_proxies(spec, work / "proxies", cfg.ingest.proxy_max_vertices)
        return spec, convert_scene_assets(spec, work / "assets")

    with (SettleAheadWorker if args.settle_ahead else BlenderWorker)(name="bench", log_dir=work) as worker:
        worker.request({"op": "ping"}, timeout=300)  # start-up is not part of a scene
        for pool_name in pools:
            pool = load_pool(pool_name, work, min_faces=args.min_faces)
            for n in sizes:
                cfg = load_config([], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}",
                                       f"scene.n_objects=[{n},{n}]", f"scene.physics_frames={args.frames}",
                                       f"compose.render_threads={threads}",
                                       f"scene.collision_proxies={str(not args.no_proxies).lower()}",
                                       *args.set])
                spec, converted = staged(cfg, pool)
                if args.cold_mesh_cache:
                    for a in converted.values():
                        for f in mesh_cache.files_of(a.visual):
                            f.unlink()
                else:
                    warm_mesh_cache(worker, converted, cfg.compose.mesh_cache)
                if not args.no_warmup and not rows:
                    warm_cfg = load_config([], [f"scene.n_objects=[{n},{n}]", "compose.resolution=64",
                                                "compose.samples=1", *args.set])
                    warm, _ = staged(warm_cfg, pool)
                    run_fresh_scene(worker, warm, work / "warmup", work / "assets", timeout_s=7200, threads=threads,
                                    mesh_cache=warm_cfg.compose.mesh_cache)
                out = work / (f"out_{pool_name}_{n}_{args.resolution}px_{args.samples}spp"
                              f"{'_noproxy' if args.no_proxies else ''}{'_set' if args.set else ''}")
                ahead: dict[str, Any] = {}
                if args.settle_ahead:
                    outcome, meta, stages, ahead = run_settled_ahead(worker, spec, out, work / "assets",
                                                                     threads=threads, mesh_cache=cfg.compose.mesh_cache)
                else:
                    outcome, meta, stages = run_fresh_scene(worker, spec, out, work / "assets", timeout_s=7200,
                                                            threads=threads, oracle=args.oracle,
                                                            mesh_cache=cfg.compose.mesh_cache)
                if meta is None:
                    rows.append({"pool": pool_name, "objects": n, "status": outcome.status, "error": outcome.error})
                    print(json.dumps(rows[-1]), file=sys.stderr)
                    continue
                t = meta["timings"]
                oracle_s = stages.pop("oracle", None)
                whole = ahead.pop("whole") if ahead else t["total"] - (oracle_s or 0.0)
                faces = {a["object_id"]: a for a in meta["spec"]["assets"]}
                row = {"pool": pool_name, "objects": n, "counted_kept": meta["n_counted"],
                       "distractors_kept": meta["n_distractors"], "dropped": meta["n_dropped"],
                       "seconds": {"stage_usd": t["stage"], **stages, "annotate_write": t["annotate"],
                                   "whole": round(whole, 3)},
                       "whole_over_rgb": round(whole / stages["rgb"], 3),
                       "physics_share": round(stages["physics"] / whole, 4),
                       "bytes": scene_bytes(Path(outcome.path)), "assets": len(faces), "out": str(outcome.path)}
                if oracle_s is not None:
                    row["oracle_s"] = oracle_s
                if ahead:
                    row["settle_ahead"] = ahead
                rows.append(row)
                print(f"{pool_name:6s} n={n:4d}  physics {stages['physics']:7.2f} s  rgb {stages['rgb']:7.2f} s  "
                      f"whole {whole:7.2f} s  whole/rgb {row['whole_over_rgb']:.3f}  physics share "
                      f"{row['physics_share']:.3f}  {row['bytes']['total'] / 1e6:.2f} MB", file=sys.stderr)
    ok = [r for r in rows if "seconds" in r]
    print("\n" + _table(ok, sizes, pools), file=sys.stderr)
    heavy = [r for r in ok if r["pool"] == "heavy"]
    print(json.dumps({"bench": "compose", "resolution": args.resolution, "samples": args.samples,
                      "frames": args.frames, "threads": threads, "cpu_count": os.cpu_count(),
                      "proxies": not args.no_proxies, "cold_mesh_cache": args.cold_mesh_cache,
                      "settle_ahead": args.settle_ahead, "scenes": rows,
                      "heavy_targets_met": bool(heavy) and all(r["whole_over_rgb"] <= 1.15 and r["physics_share"] <= 0.05
                                                                for r in heavy)}))
    return 0


def run_settled_ahead(worker: Any, spec: Any, out: Path, assets: Path, *, threads: int,
                      mesh_cache: str) -> tuple[Any, Any, dict[str, float], dict[str, Any]]:
    """Three copies of ``spec`` through a SettleAheadWorker, each settling during the previous render;
    the middle copy's outcome, metadata and worker stage seconds, and what the pipeline did."""
    import shutil
    import threading
    import time
    from dataclasses import replace

    from pools import worker_stages

    from mixcount.config import load_config
    from mixcount.run.scene_task import WRITTEN, SceneTask, run_scene_task, stage_scene
    from mixcount.worker.contract import SceneOutputs

    shutil.rmtree(out, ignore_errors=True)
    outputs = replace(SceneOutputs.from_config(load_config().compose), mesh_cache=mesh_cache)
    tasks = [SceneTask(spec=replace(spec, scene_id=f"{spec.scene_id}_copy{k}"), out_dir=str(out),
                       assets_dir=str(assets), timeout_s=7200, threads=threads, outputs=outputs) for k in range(3)]
    staged = [stage_scene(t) for t in tasks]
    ends, outcomes, starter = [], [], None
    for k, (task, st) in enumerate(zip(tasks, staged)):
        if k + 1 < len(tasks):  # the next copy settles beside this one (begin_settle waits for its turn)
            starter = threading.Thread(target=worker.begin_settle, args=(staged[k + 1].request,), daemon=True)
            starter.start()
        outcomes.append(run_scene_task(task, worker, st))
        ends.append(time.perf_counter())
        if starter is not None:
            starter.join()
    if any(o.status != WRITTEN for o in outcomes):
        bad = next(o for o in outcomes if o.status != WRITTEN)
        return bad, None, {}, {}
    metas = [json.loads((Path(o.path) / "metadata.json").read_text()) for o in outcomes]
    poses = [[(o["name"], o["status"], o.get("matrix_world")) for o in m["objects"]] for m in metas]
    stages = worker_stages(metas[1])
    settled = [d for d in metas[1]["diagnostics"] if d.get("kind") == "settled_ahead"]
    return outcomes[1], metas[1], stages, {
        "whole": round(ends[1] - ends[0], 3), "settled_in_companion": bool(settled),
        "companion_seconds": settled[0]["seconds"] if settled else None,
        "copy0_rgb_s": worker_stages(metas[0])["rgb"],
        "same_poses": poses[0] == poses[1] == poses[2], "failures": list(worker.settle_failures)}


def _table(rows: list[dict], sizes: list[int], pools: list[str]) -> str:
    """Pools side by side: one line per size, physics s / whole-over-RGB / physics share / MB per pool."""
    head = "objects | " + " | ".join(f"{p}: physics s, whole/rgb, physics %, MB" for p in pools)
    lines = [head, "-" * len(head)]
    by = {(r["pool"], r["objects"]): r for r in rows}
    for n in sizes:
        cells = []
        for p in pools:
            r = by.get((p, n))
            cells.append("-" if r is None else f"{r['seconds']['physics']:.2f}, {r['whole_over_rgb']:.3f}, "
                                               f"{100 * r['physics_share']:.1f} %, {r['bytes']['total'] / 1e6:.2f}")
        lines.append(f"{n:7d} | " + " | ".join(cells))
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
