"""Benchmark re-rendering one settled pile from K new views (``mixcount render``) against a fresh scene.

    .venv/bin/python bench/rerender.py                         # 256 px, 16 spp, 8 new views, 30-60 objects
    .venv/bin/python bench/rerender.py --resolution 512 --samples 32 --views 8
    .venv/bin/python bench/rerender.py --smoke                 # seconds: 32 px, 1 spp, 3 views (the suite)

One scene is composed (demo library, configs/quick.toml), then in ONE bpy worker, after a warm-up
re-render outside the clock (Cycles' and OIDN's one-off start-up):
``fresh``  - the same scene.usda through the ``scene`` op (import, physics, placement, id passes, RGB: what a
             fresh scene of the same pile costs, one camera);
``own_view`` - the ``rerender`` op with the scene's own camera only (the fresh scene's image, no physics);
``views``  - the ``rerender`` op with the K new views only (paper camera rule around the settled pile),
             Cycles' persistent data on: the import once, no physics, one RGB render per view;
``views_no_persistent`` - the same request with persistent data off (what keeping Cycles' scene data saves).
Per view: ``rgb_s`` (its RGB render) and ``view_s`` = rgb_s + the request's per-view work shared evenly
(frame check, silhouettes, id passes, passes); the first view also pays the import (``first_view_s``).
Figures: ``total_s`` (the whole K-view request), ``later_over_first`` (view k's view_s / view 1's for
k = 2..K), ``fresh_over_view`` (fresh scene / view k's view_s for k = 2..K) with their medians, and the
same in CPU seconds of the worker process (``*_cpu``: all its threads; on a shared machine other processes
stretch wall times, much less CPU times). One JSON line on stdout, a short summary on stderr.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SHARED_STEPS = ("frame_check", "silhouettes", "id_pass", "visibility", "write_passes", "poses")


def _catalog(work: Path) -> Path:
    """A 12-object demo catalog under ``work/cat`` (made once; every active object in train)."""
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject, Split
    from mixcount.config import load_config
    from mixcount.demo.library import generate_demo_library

    root = work / "cat"
    if (root / "catalog.db").exists():
        return root / "catalog.db"
    generate_demo_library(root / "lib", seed=0, n_objects=12)
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")
    ingest_paths(cat, [root / "lib"], config=load_config(["quick"], ["ingest.workers=1"]))
    with cat.session() as session:
        for obj in session.query(CatalogObject).filter_by(status="active").order_by(CatalogObject.id):
            session.add(Split(object_id=obj.id, split="train", method="random"))
        session.commit()
    cat.close()
    return root / "catalog.db"


CPU: dict[str, float] = {}  # the last request's CPU seconds of the worker process (all its threads)


def _cpu(pid: int) -> float:
    import psutil

    t = psutil.Process(pid).cpu_times()
    return float(t.user + t.system)


def _request(worker: Any, req: Any, timeout: float) -> tuple[Any, float]:
    """Wall seconds of one request (and its worker CPU seconds in ``CPU["last"]``: the measure that other
    processes on a shared machine disturb least)."""
    from mixcount.worker.contract import SceneResult

    worker.start()
    c, t = _cpu(worker.pid), time.perf_counter()
    answer = worker.request({"op": req.OP, "request": req.to_dict()}, timeout=timeout)
    seconds = time.perf_counter() - t
    CPU["last"] = round(_cpu(worker.pid) - c, 3)
    if not answer.get("ok"):
        raise RuntimeError(answer.get("error"))
    return SceneResult.from_dict(answer["result"]), seconds


def _per_view(result: Any, first_extra: float, cpu_total: float) -> dict[str, Any]:
    """Per view: RGB wall / CPU seconds; ``view_s`` / ``view_cpu_s`` add the request's per-view work (wall)
    or the rest of the request's CPU (import included), shared evenly."""
    diag = next(d for d in result.diagnostics if d.get("kind") == "rgb_per_view")
    rgb, rgb_cpu = diag["seconds"], diag["cpu_seconds"]
    shared = sum(result.timings.get(k, 0.0) for k in SHARED_STEPS) / len(rgb)
    view_s = [round(r + shared, 4) for r in rgb]
    shared_cpu = max(0.0, cpu_total - sum(rgb_cpu)) / len(rgb)
    return {"rgb_s": rgb, "view_s": view_s, "first_view_s": round(view_s[0] + first_extra, 4),
            "rgb_cpu_s": rgb_cpu, "view_cpu_s": [round(r + shared_cpu, 3) for r in rgb_cpu], "cpu_s": cpu_total,
            "timings": dict(result.timings)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--objects", default="[30,60]", help="scene.n_objects")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--smoke", action="store_true", help="seconds: 32 px, 1 spp, 3 views (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:
        args.resolution, args.samples, args.views, args.objects = 32, 1, 3, "[12,16]"

    from mixcount.cli import main as cli
    from mixcount.config import load_config
    from mixcount.dataset.scene_writer import tmp_dir_for
    from mixcount.run.rerender import copy_scene_files, finished_scenes, link_assets, new_views, own_views
    from mixcount.scene.spec import SceneSpec
    from mixcount.worker.client import BlenderWorker
    from mixcount.worker.contract import SceneOutputs, SceneRequest
    from mixcount.worker.rerender_contract import RerenderRequest

    work = args.work or Path(tempfile.mkdtemp(prefix="bench-rerender-"))
    work.mkdir(parents=True, exist_ok=True)
    db = _catalog(work)
    src = work / f"src-{args.resolution}-{args.samples}-{args.seed}"
    if not src.exists():
        rc = cli(["--db", str(db), "--config", "quick", "--set", f"scene.n_objects={args.objects}", "compose", "--n", "1",
                  "--seed", str(args.seed), "--resolution", str(args.resolution), "--samples", str(args.samples),
                  "--out", str(src)])
        if rc != 0:
            raise SystemExit(f"compose exited {rc}")
    scene_dir = finished_scenes(src)[0]
    meta = json.loads((scene_dir / "metadata.json").read_text())
    spec = SceneSpec.from_dict(meta["spec"])
    cfg = load_config(["quick"], [f"rerender.new_views={args.views}", "compose.render_threads=0"])
    out = work / "out"
    shutil.rmtree(out, ignore_errors=True)
    (out / "scenes").mkdir(parents=True)
    link_assets(src, out)
    outputs = SceneOutputs.from_config(cfg.compose)
    poses = {o["path"]: tuple(tuple(float(v) for v in r) for r in o["matrix_world"])
             for o in meta["objects"] if o["status"] == "kept"}
    views = tuple(new_views(meta, spec, cfg))

    own = tuple(own_views(meta))[:1]

    def rerender(persistent: bool, tag: str, only: int = 0, cams: tuple[Any, ...] = ()) -> Any:
        tmp = tmp_dir_for(out, f"{spec.scene_id}-{tag}", tag)
        tmp.mkdir(parents=True)
        shutil.copyfile(scene_dir / "settled.usda", tmp / "scene.usda")
        copy_scene_files(scene_dir, tmp)  # the floor's textures/ beside the copied stage, as `mixcount render` does
        return RerenderRequest(stage=str(tmp / "scene.usda"), out_dir=str(tmp), threads=0, oracle=False,
                               passes=outputs.passes, depth_format=outputs.depth_format,
                               normal_format=outputs.normal_format, mesh_cache=outputs.mesh_cache, poses=poses,
                               views=cams or (views[:only] if only else views), resolution=0, samples=0, denoise="scene", rule="all_cameras",
                               device="cpu", persistent_data=persistent)

    worker = BlenderWorker(name="bench-rerender", log_dir=work)
    try:
        _request(worker, rerender(True, "warm", only=1), 3600)  # one-off start-up outside the clock
        fresh_tmp = tmp_dir_for(out, f"{spec.scene_id}-fresh", "fresh")
        fresh_tmp.mkdir(parents=True)
        shutil.copyfile(scene_dir / "scene.usda", fresh_tmp / "scene.usda")
        copy_scene_files(scene_dir, fresh_tmp)
        fresh_req = SceneRequest.for_outputs(outputs, stage=str(fresh_tmp / "scene.usda"), out_dir=str(fresh_tmp),
                                             threads=0, oracle=False)
        fresh_result, fresh_s = _request(worker, fresh_req, 3600)
        fresh_cpu = CPU["last"]
        res_own, own_s = _request(worker, rerender(False, "own", cams=own), 3600)
        own_cpu = CPU["last"]
        res_on, total_on = _request(worker, rerender(True, "on"), 3600)
        on = _per_view(res_on, res_on.timings.get("import", 0.0), CPU["last"])
        res_off, total_off = _request(worker, rerender(False, "off"), 3600)
        off = _per_view(res_off, res_off.timings.get("import", 0.0), CPU["last"])
    finally:
        worker.close()
    later = [round(v / on["view_s"][0], 3) for v in on["view_s"][1:]]
    fresh_over = [round(fresh_s / v, 2) for v in on["view_s"][1:]]
    later_cpu = [round(v / on["view_cpu_s"][0], 3) for v in on["view_cpu_s"][1:]]
    fresh_over_cpu = [round(fresh_cpu / v, 2) for v in on["view_cpu_s"][1:]]
    doc = {
        "bench": "rerender", "resolution": args.resolution, "samples": args.samples, "views": len(views),
        "counted_kept": sum(1 for o in meta["objects"] if o["status"] == "kept" and o["role"] == "counted"),
        "fresh": {"seconds": round(fresh_s, 3), "cpu_s": fresh_cpu, "timings": dict(fresh_result.timings)},
        # the scene's own camera re-rendered alone (no physics): the same image as the fresh scene's
        "own_view": {"seconds": round(own_s, 3), "cpu_s": own_cpu, "timings": dict(res_own.timings)},
        "fresh_over_own_view": round(fresh_s / own_s, 3),
        "total_s": round(total_on, 3), "total_no_persistent_s": round(total_off, 3),
        "views_persistent": on, "views_no_persistent": off,
        "later_over_first": later, "later_over_first_median": statistics.median(later) if later else 1.0,
        "fresh_over_view": fresh_over, "fresh_over_view_median": statistics.median(fresh_over) if fresh_over else 0.0,
        "later_over_first_cpu": later_cpu, "later_over_first_cpu_median": statistics.median(later_cpu) if later_cpu else 1.0,
        "fresh_over_view_cpu": fresh_over_cpu,
        "fresh_over_view_cpu_median": statistics.median(fresh_over_cpu) if fresh_over_cpu else 0.0,
        "rgb_persistent_over_not_median": round(statistics.median(
            a / b for a, b in zip(on["rgb_s"][1:], off["rgb_s"][1:])), 3) if len(views) > 1 else 1.0,
    }
    print(f"{len(views)} views at {args.resolution} px / {args.samples} spp: total {doc['total_s']} s "
          f"(persistent data off: {doc['total_no_persistent_s']} s); fresh scene {doc['fresh']['seconds']} s, "
          f"its camera re-rendered {doc['own_view']['seconds']} s; "
          f"view 1 {on['first_view_s']} s (with the import), views 2-{len(views)} {on['view_s'][1:]} s; "
          f"later/first median {doc['later_over_first_median']}, fresh/view median {doc['fresh_over_view_median']}; "
          f"in CPU s: later/first {doc['later_over_first_cpu_median']}, fresh/view {doc['fresh_over_view_cpu_median']}",
          file=sys.stderr)
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
