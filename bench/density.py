"""Scene density: what default scenes keep of what they spawn, per pool (issue 23's figures).

    .venv/bin/python bench/density.py --work W                        # seeds 100-123, light then heavy pool
    .venv/bin/python bench/density.py --work W --pool heavy --seeds 100-123 --scenes-out heavy.jsonl
    .venv/bin/python bench/density.py --work W --pool light --scenes 4 --set scene.n_cameras=2

Scenes are sampled with the default config (the paper's: n ~ UniformInt[30, 200], containers as drawn, no
ingested environments or materials) from the chosen pool (bench/pools.py: ``light`` = the demo library,
``heavy`` = its capture-like >= 200k-face copy), with collision proxies and container collision meshes as
ingest stores them, and run end to end by the worker (physics, checks, visibility, passes, RGB, scene
files) at a reduced resolution and sample count (``--resolution`` / ``--samples``: what is kept hardly
depends on them). Each scene's ``metadata.json`` is read by :mod:`mixcount.evaluate.scene_density`.

stdout: one JSON line per pool: counted retention (kept / spawned) overall and in container /
no-container scenes, mean counted kept per scene, distractors spawned / kept per scene, drop reasons
(counts and shares of all spawned bodies), bodies lost off the floor (below_floor + flung_out) and
classes that ended with no visible instance. stderr: one line per scene and a table; ``--scenes-out``
also writes the per-scene records as JSON lines.

Before / after: mixcount is imported as Python resolves it (``PYTHONPATH`` first, else this checkout),
so ``cd OLD && PYTHONPATH=OLD python NEW/bench/density.py`` measures the code in OLD with this bench;
the figures are always computed by this checkout's ``mixcount/evaluate/scene_density.py``. The run prints
where mixcount came from in this process and in the bpy worker (``python -m`` puts the current folder
first on the worker's path: run from OLD) and stops if the two differ.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
sys.path.append(str(ROOT))  # last: a PYTHONPATH (or installed) mixcount wins, see the docstring


def _density_module() -> ModuleType:
    """This checkout's mixcount/evaluate/scene_density.py (stdlib only), whatever mixcount is imported."""
    spec = importlib.util.spec_from_file_location("_bench_density", ROOT / "mixcount" / "evaluate" / "scene_density.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _seeds(text: str) -> list[int]:
    """``100-123`` or ``1,5,9`` (or both, comma-separated)."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        out.extend(range(int(lo), int(hi) + 1) if hi else [int(lo)])
    return out


def _seed_ranges(seeds: list[int]) -> str:
    """``[100, 101, 102, 120]`` -> ``100-102,120`` (the inverse of :func:`_seeds`)."""
    parts: list[str] = []
    for s in sorted(set(seeds)):
        if parts and s == int(parts[-1].rpartition("-")[2]) + 1:
            parts[-1] = f"{parts[-1].partition('-')[0]}-{s}"
        else:
            parts.append(str(s))
    return ",".join(parts)


def worker_mixcount_dir(worker: Any) -> str:
    """The mixcount package folder the bpy worker imported, read from the traceback of a request it
    must refuse (an empty scene request fails inside mixcount/engine/worker_main.py)."""
    answer = worker.request({"op": "scene", "request": {}}, timeout=300)
    m = re.search(r'File "([^"]+)/engine/worker_main\.py"', answer.get("traceback", ""))
    if answer.get("ok") or m is None:
        raise SystemExit(f"cannot tell where the worker's mixcount comes from: {answer}")
    return m.group(1)


def run_pool(pool_name: str, args: Any, work: Path, worker: Any, density: ModuleType,
             scenes_out: Any) -> dict[str, Any]:
    from pools import load_pool, run_fresh_scene, warm_mesh_cache, with_proxies

    from mixcount.config import load_config
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets

    cfg = load_config([], [f"compose.resolution={args.resolution}", f"compose.samples={args.samples}", *args.set])
    pool = load_pool(pool_name, work)
    rows, failed = [], []
    for seed in args.seeds:
        t = time.perf_counter()
        spec = with_proxies(sample_scene(seed, "train", cfg, pool), work / "proxies", cfg.ingest.proxy_max_vertices)
        converted = convert_scene_assets(spec, work / "assets")
        warm_mesh_cache(worker, converted, cfg.compose.mesh_cache)
        outcome, meta, _ = run_fresh_scene(worker, spec, work / f"out_{pool_name}", work / "assets",
                                           timeout_s=args.timeout, threads=args.threads,
                                           mesh_cache=cfg.compose.mesh_cache)
        if meta is None:
            failed.append({"seed": seed, "status": outcome.status, "error": str(outcome.error)[:500]})
            print(json.dumps({"bench": "density.scene", "pool": pool_name, **failed[-1]}), file=sys.stderr)
            continue
        row = {"bench": "density.scene", "pool": pool_name, **density.scene_density(meta),
               "environment": meta["spec"]["environment"]["kind"], "seconds": round(time.perf_counter() - t, 1)}
        rows.append(row)
        line = json.dumps(row)
        print(line, file=sys.stderr, flush=True)
        if scenes_out is not None:
            scenes_out.write(line + "\n")
            scenes_out.flush()
    summary = density.summarise_density(rows)
    _table(pool_name, rows)
    return {"bench": "density", "pool": pool_name, "seeds": _seed_ranges(args.seeds),
            "resolution": args.resolution, "samples": args.samples, "set": list(args.set),
            "environments": sorted({r["environment"] for r in rows}), **summary, "failed": failed}


def _table(pool_name: str, rows: list[dict[str, Any]]) -> None:
    print(f"\n{pool_name}: seed | container | counted kept/spawned | distractors kept/spawned | empty classes | drops",
          file=sys.stderr)
    for r in rows:
        print(f"  {r['seed']:>4} | {'yes' if r['container'] else 'no ':>9} | {r['counted_kept']:>4}/{r['counted_spawned']:<4}"
              f"          | {r['distractors_kept']:>2}/{r['distractors_spawned']:<2}                    | "
              f"{len(r['classes_without_instances']):>13} | {r['counted_drops']}", file=sys.stderr)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pool", choices=("light", "heavy", "both"), default="both")
    ap.add_argument("--seeds", type=_seeds, default=None, help="e.g. 100-123 or 1,4,7 (default: --scenes from 100)")
    ap.add_argument("--scenes", type=int, default=24, help="scenes per pool when --seeds is not given")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2, help="Cycles threads")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per scene")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--scenes-out", type=Path, default=None, help="also write the per-scene JSON lines here")
    ap.add_argument("--work", type=Path, default=None, help="pools, assets and scenes (reused across runs)")
    ap.add_argument("--smoke", action="store_true", help="seconds: tiny sizes, same code path (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:  # one scene of the light pool at 32 px, 1 sample, 1 thread
        args.pool, args.seeds, args.resolution, args.samples, args.threads = "light", [100], 32, 1, 1
        args.set = [*args.set, "scene.physics_frames=60"]
    args.seeds = args.seeds or list(range(100, 100 + args.scenes))

    import mixcount
    from mixcount.worker.client import BlenderWorker

    density = _density_module()
    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-density-"))
    here = str(Path(mixcount.__file__).resolve().parent)
    pools = ("light", "heavy") if args.pool == "both" else (args.pool,)
    scenes_out = open(args.scenes_out, "a") if args.scenes_out else None
    try:
        with BlenderWorker(name="bench-density", log_dir=work) as worker:
            worker.request({"op": "ping"}, timeout=300)
            there = str(Path(worker_mixcount_dir(worker)).resolve())
            print(f"mixcount imported from {here} (bench process) and {there} (bpy worker)", file=sys.stderr)
            if here != there:
                raise SystemExit("the bench and its worker import different mixcount copies: run from the "
                                 "folder on PYTHONPATH")
            for name in pools:
                print(json.dumps({**run_pool(name, args, work, worker, density, scenes_out), "mixcount": here}),
                      flush=True)
    finally:
        if scenes_out is not None:
            scenes_out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
