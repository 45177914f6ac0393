"""Settling quality per scene: what the physics keeps and loses, without rendering.

    .venv/bin/python bench/settle.py --work W                         # seeds 0,2,4,5,7,8, heavy pool
    .venv/bin/python bench/settle.py --work W --seeds 0 --substeps 4 --below   # where the losses lie
    .venv/bin/python bench/settle.py --work W --split-impulse         # experiment: Bullet's split impulse
    .venv/bin/python bench/settle.py --work W --set scene.spawn_release_waves=false   # stacked, not in waves

Scenes are sampled with the default config (the paper's: 30-200 objects, containers as drawn) from the
chosen pool with proxies and container collision meshes as ingest stores them, written as stages, and
each is settled by the worker's own code in a fresh bpy process: import, :func:`settle` with the camera
(the early stop), the settle checks and the frame check. One JSON line per seed: frames run, physics
seconds, drops by reason, counted objects kept, highest spawn height, the median distance bodies
settle from the scene centre (scatter) and how many bodies spawn waves released later, then a table on
stderr. ``--split-impulse`` is an experiment (Bullet's split impulse; docs/performance.md, settling).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def _write_stages(args: Any, work: Path) -> list[tuple[int, Path]]:
    from pools import load_pool, with_proxies

    from mixcount.config import load_config
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets, write_stage

    cfg = load_config([], list(args.set))
    pool = load_pool(args.pool, work)
    out = []
    for seed in args.seeds:
        spec = with_proxies(sample_scene(seed, "train", cfg, pool), work / "proxies", cfg.ingest.proxy_max_vertices)
        convert_scene_assets(spec, work / "assets")
        stage = write_stage(spec, work / "settle", assets_dir=work / "assets", scene_dir=work / "settle" / f"seed_{seed}")
        out.append((seed, stage))
    return out


def _settle_one(args: Any) -> dict[str, Any]:
    """Settle one stage in this (fresh) process with the worker's code; the JSON record."""
    import collections
    import dataclasses
    import time

    import numpy as np

    from mixcount.config import load_config
    from mixcount.engine import physics as PH
    from mixcount.engine import scene_job as J
    from mixcount.engine.scene_build import load_scene
    from mixcount.engine.visibility import camera_model
    from mixcount.worker.contract import SceneOutputs, SceneRequest

    state = load_scene(SceneRequest.for_outputs(SceneOutputs.from_config(load_config().compose), stage=args.run_stage,
                                                out_dir=tempfile.mkdtemp(prefix="settle-"), threads=2, oracle=False))
    camera = camera_model(state.scene, state.cam_objs[0])
    spawn = np.array([np.array(o.spawn_matrix)[:3, 3] for o in state.objects])
    if args.substeps:
        state.spec = dataclasses.replace(state.spec, physics=dataclasses.replace(state.spec.physics,
                                                                               substeps=args.substeps))
    add_bodies = PH._add_bodies

    def add(scene: Any, bodies: list[Any]) -> None:
        add_bodies(scene, bodies)
        scene.rigidbody_world.use_split_impulse = bool(args.split_impulse)

    PH._add_bodies = add
    t = time.perf_counter()
    settled = J.settle(state, camera)
    seconds = time.perf_counter() - t
    J.place_settled(state, settled)
    J.check_frame(state, J.place_after_physics(state, settled.poses, J.Timer()).cameras)
    drops = collections.Counter(d["reason"] for d in state.diagnostics if d.get("kind") == "dropped")
    rest = next(d for d in state.diagnostics if d.get("kind") == "rest")
    final = np.array([np.array(o.matrix_world)[:3, 3] for o in state.objects])
    if args.below:
        for d in state.diagnostics:
            if d.get("kind") == "dropped" and d["reason"] == "below_floor":
                o = next(o for o in state.objects if o.name == d["object"])
                c = np.array(o.matrix_world)[:3, 3]
                print(f"  below_floor {o.name}: size {o.size_m:.2f} m, centre {np.round(c, 2).tolist()}, "
                      f"{float(np.hypot(c[0], c[1])):.1f} m from the centre, lowest point {d.get('min_z', float('nan')):.2f} m",
                      file=sys.stderr)
    cont = state.spec.container
    return {"bench": "settle", "stage": args.run_stage, "objects": len(state.objects),
            "container": next((a.name for a in state.spec.assets if cont and a.object_id == cont.object_id), None),
            "substeps": state.spec.physics.substeps, "frames_run": rest["frames_run"], "physics_s": round(seconds, 2),
            "drops": dict(sorted(drops.items())), "counted_kept": len(state.kept("counted")),
            "spawn_max_z": round(float(spawn[:, 2].max()), 1),
            "median_settle_distance_m": round(float(np.median(np.hypot(final[:, 0], final[:, 1]))), 2),
            "released_later": rest.get("released_later", 0), "last_release": rest.get("last_release", 1),
            "split_impulse": bool(args.split_impulse)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=lambda s: [int(x) for x in s.split(",")], default=[0, 2, 4, 5, 7, 8])
    ap.add_argument("--pool", choices=("light", "heavy"), default="heavy")
    ap.add_argument("--substeps", type=int, default=0, help="override the stage's substeps (0: keep)")
    ap.add_argument("--split-impulse", action="store_true", help="experiment: Bullet's split impulse")
    ap.add_argument("--below", action="store_true", help="print where each below_floor body lies")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--run-stage", default="", help=argparse.SUPPRESS)  # internal: settle one stage here
    ap.add_argument("--smoke", action="store_true", help="seconds: tiny sizes, same code path (the suite runs it)")
    args = ap.parse_args()
    if args.smoke:  # one stage of the light pool, 12 objects, 60 frames
        args.seeds, args.pool = [0], "light"
        args.set = [*args.set, "scene.n_objects=[12,12]", "scene.physics_frames=60"]
    if args.run_stage:
        print(json.dumps(_settle_one(args)))
        return 0
    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-bench-settle-"))
    rows = []
    for seed, stage in _write_stages(args, work):
        cmd = [sys.executable, __file__, "--run-stage", str(stage), "--substeps", str(args.substeps)]
        cmd += ["--split-impulse"] if args.split_impulse else []
        cmd += ["--below"] if args.below else []
        done = subprocess.run(cmd, capture_output=True, text=True)
        sys.stderr.write("".join(line + "\n" for line in done.stderr.splitlines() if line.startswith("  below_floor")))
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith('{"bench"')]
        if done.returncode != 0 or not lines:
            print(f"seed {seed}: settling failed\n{done.stderr[-2000:]}", file=sys.stderr)
            continue
        row = {"seed": seed, **json.loads(lines[-1])}
        rows.append(row)
        print(json.dumps(row), flush=True)
    print("\nseed | objects | container | frames | physics s | kept counted | drops | spawn max z | median settle distance",
          file=sys.stderr)
    for r in rows:
        print(f"{r['seed']:>4} | {r['objects']:>7} | {str(r['container'])[:24]:<24} | {r['frames_run']:>6} | "
              f"{r['physics_s']:>9} | {r['counted_kept']:>12} | {r['drops']} | {r['spawn_max_z']} m | "
              f"{r['median_settle_distance_m']} m", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
