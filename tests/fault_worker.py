"""A bpy worker entry for tests only: ``python -m tests.fault_worker`` serves the production handlers of
:mod:`mixcount.engine.worker_main` plus faults the tests of timeouts and crashes need:

* ``{"op": "sleep", "seconds": s}`` - a hung request;
* a ``canonical`` request whose stem is ``hang_<s>`` hangs ``s`` seconds, one whose stem is
  ``crash_<code>`` kills the process mid-job (``os._exit(code)``); any other renders normally;
* ``{"op": "border_check", "stage": path, "out_dir": path, "drop": k}`` - the visibility loop's border
  re-render against a full one: a settled scene, its id pass, the ``k`` most visible objects removed, the
  changed region re-rendered and pasted (Cycles' sync kept between the two, as in the loop), then a full
  render from a fresh sync; answers which passes are identical.
* ``{"op": "rest_stop"}`` - the simulation's early stop: two cubes resting on a floor and three falling
  from 30 m at x >= 10, simulated with every body waited for and with only those at x < 5; answers the
  frames each run simulated.
* ``{"op": "release_wave"}`` - a spawn wave: a cube held until frame 40 at (5, 0, 10) beside two resting
  ones; answers its centre at every rest check, its settled pose, the frames run and whether any
  animation is left on it.
* ``{"op": "mesh_cache", "stage": path, "out_dir": path}`` - the .blend mesh cache and the unlit id
  pass: the stage loaded with no cache, with a cold cache (files written), a warm one (files appended)
  one whose first file was truncated, and one whose last file cannot be written (a folder in its
  place); answers each load's cache events and whether every load's id
  passes and small RGB render equal the uncached one's, and whether a lit id pass equals the unlit one.

* ``{"op": "leave_cycle"}`` - leaves one 300 MB object in a reference cycle that only a full collection frees (as
  the glTF importer's do) and answers how many left by earlier requests are still alive.
Tests select it with ``monkeypatch.setattr("mixcount.worker.client.WORKER_MODULE", "tests.fault_worker")``.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from typing import Any

from mixcount.config import load_config
from mixcount.engine import worker_main


def sleep(req: dict[str, Any]) -> dict[str, Any]:
    time.sleep(float(req["seconds"]))
    return {"ok": True}


def canonical(req: dict[str, Any]) -> dict[str, Any]:
    kind, _, value = str(req["request"]["stem"]).partition("_")
    if kind == "hang":
        time.sleep(float(value))
    if kind == "crash":
        os._exit(int(value))
    return worker_main.HANDLERS["canonical"](req)


def border_check(req: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    import mixcount.scene_decisions as D
    from mixcount.engine import render_passes as P
    from mixcount.engine import scene_build as B
    from mixcount.engine import scene_job as J
    from mixcount.worker.contract import SceneOutputs, SceneRequest

    state = B.load_scene(SceneRequest.for_outputs(SceneOutputs.from_config(load_config().compose), stage=req["stage"],
                                                  out_dir=req["out_dir"], threads=2, oracle=False))
    settled = J.settle(state)
    J.place_settled(state, settled)
    J.check_frame(state, J.place_after_physics(state, settled.poses, J.Timer()).cameras)
    exr = state.out_dir / "_border.exr"
    with P.id_pass_series(state.scene):  # as the visibility loop renders: Cycles' sync kept
        before = P.render_id_passes(state.scene, exr)
        kept = state.kept()
        seen = {state.objects[i].instance_id: int((before["index"] == state.objects[i].instance_id).sum())
                for i in kept}
        drop = sorted(seen, key=lambda k: -seen[k])[: int(req["drop"])]
        region = D.changed_region(before["index"], drop)
        for i in kept:
            if state.objects[i].instance_id in drop:
                state.drop(i, D.OCCLUDED, "test")
        assert region is not None
        pasted = D.paste_region(before, P.render_id_passes(state.scene, exr, region), region)
        twins = [o.name for o in state.scene.objects if o.name.endswith(P.TWIN_SUFFIX)]
    plain = P.render_id_passes(state.scene, exr)  # outside a series: no twins, Cycles' own sync
    with P.id_pass_series(state.scene):  # a fresh sync of the scene without them, as the loop renders
        full = P.render_id_passes(state.scene, exr)
    return {"ok": True, "region": list(region), "dropped_px": sum(seen[k] for k in drop),
            "changed_px": int((full["index"] != before["index"]).sum()),
            "equal": {k: bool(np.array_equal(pasted[k], full[k])) for k in ("index", "depth", "normal")},
            "dropped_still_seen": int(np.isin(pasted["index"], drop).sum()),
            "twins": len(twins), "twins_left": sum(1 for o in state.scene.objects if o.name.endswith(P.TWIN_SUFFIX)),
            "plain_index_equal": bool(np.array_equal(plain["index"], full["index"])),
            "plain_depth_rel": float(np.max(np.abs(plain["depth"] - full["depth"]) / np.maximum(full["depth"], 1e-6)))}


def _cube(scene: Any, name: str, loc: tuple[float, float, float], size: float) -> Any:
    """A cube mesh object of edge ``size`` at ``loc``, linked into ``scene``."""
    import bpy

    mesh = bpy.data.meshes.new(name)
    h = size / 2
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    obj.location = loc
    return obj


def rest_stop(req: dict[str, Any]) -> dict[str, Any]:
    import bpy
    import numpy as np

    from mixcount.engine.physics import Body, simulate

    out: dict[str, Any] = {"ok": True}
    for mode in ("all", "near"):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        # more falling bodies than the rolling allowance (REST_ROLLING_MIN) lets move
        bodies = [Body(_cube(scene, "floor", (0.0, 0.0, -1.0), 2.0 * 20), "passive", "BOX")]
        bodies += [Body(_cube(scene, f"resting{i}", (-2.0 * i, 0.0, 0.55), 1.0), "active", "CONVEX_HULL")
                   for i in range(2)]
        bodies += [Body(_cube(scene, f"falling{i}", (10.0 + 2 * i, 0.0, 30.0), 1.0), "active", "CONVEX_HULL")
                   for i in range(3)]
        bodies[0].obj.scale = (1.0, 1.0, 0.05)
        run = simulate(scene, bodies, frames=200, substeps=8, iterations=4, gravity=9.81, rest_speed=0.05,
                       waited_for=(lambda c: np.asarray(c[:, 0] < 5.0)) if mode == "near" else None)
        out[mode] = {"frames_run": run.frames_run, "waited_for": run.waited_for,
                     "falling_z": float(bpy.data.objects["falling0"].matrix_world.translation.z)}
    return out


def scaled_drop(req: dict[str, Any]) -> dict[str, Any]:
    """A 2.2 cm cube proxy at x51 (a 1.12 m body) dropped 15 m onto a hull floor, collided the worker's way
    (scale baked into the collider's mesh, ``scaled_proxy_collider``) and the naive way (object scale)."""
    import bpy
    import mathutils
    import numpy as np

    from mixcount.engine.physics import Body, simulate
    from mixcount.engine.scene_build import pose_with_scale, scaled_proxy_collider

    h = 0.011
    corners = np.array([(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)])
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    out: dict[str, Any] = {"ok": True}
    for mode in ("baked", "object_scale"):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        floor_mesh = bpy.data.meshes.new("floor")
        floor_mesh.from_pydata((corners / h * [20.0, 20.0, 2.5] - [0.0, 0.0, 2.5]).tolist(), [], faces)
        floor = bpy.data.objects.new("floor", floor_mesh)
        scene.collection.objects.link(floor)
        proxy = bpy.data.meshes.new("proxy")
        proxy.from_pydata(corners.tolist(), [], faces)
        m = np.eye(4)
        m[:3, :3] = np.array(mathutils.Euler((0.3, 0.2, 0.0)).to_matrix()) * 51.1
        m[:3, 3] = (3.0, 0.0, 15.0)
        scale = None
        if mode == "baked":
            die, scale = scaled_proxy_collider(scene, "die", proxy, m)
        else:
            die = bpy.data.objects.new("die", proxy)
            scene.collection.objects.link(die)
            die.matrix_world = mathutils.Matrix(m.tolist())
        run = simulate(scene, [Body(floor, "passive", "CONVEX_HULL"), Body(die, "active", "CONVEX_HULL")],
                       frames=300, substeps=8, iterations=4, gravity=9.81, rest_speed=0.0)
        pose = run.matrices[die.name] if scale is None else pose_with_scale(run.matrices[die.name], scale)
        world = np.c_[corners, np.ones(8)] @ pose.T
        out[mode] = {"lowest": float(world[:, 2].min()), "centre_z": float(pose[2, 3]),
                     "size": float(np.linalg.norm(pose[:3, 0]) * 2 * h)}
    return out


def release_wave(req: dict[str, Any]) -> dict[str, Any]:
    import bpy
    import numpy as np

    from mixcount.engine.physics import Body, simulate

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    bodies = [Body(_cube(scene, "floor", (0.0, 0.0, -1.0), 2.0 * 20), "passive", "BOX")]
    bodies += [Body(_cube(scene, f"resting{i}", (-2.0 * (i + 1), 0.0, 0.55), 1.0), "active", "CONVEX_HULL")
               for i in range(2)]
    bodies.append(Body(_cube(scene, "held", (5.0, 0.0, 10.0), 1.0), "active", "CONVEX_HULL"))
    bodies[0].obj.scale = (1.0, 1.0, 0.05)
    seen: list[list[float]] = []

    def record(centres: Any) -> Any:
        seen.append([float(v) for v in centres[2]])
        return np.ones(len(centres), dtype=bool)

    run = simulate(scene, bodies, frames=100, substeps=8, iterations=4, gravity=9.81, rest_speed=0.05,
                   waited_for=record, releases={"held": 40})
    held = bpy.data.objects["held"]
    return {"ok": True, "centres": seen, "frames_run": run.frames_run, "last_release": run.last_release,
            "settled": [float(v) for v in run.matrices["held"][:3, 3]], "animation_left": held.animation_data is not None,
            "pose": [float(v) for v in held.matrix_world.translation]}


def mesh_cache(req: dict[str, Any]) -> dict[str, Any]:
    import shutil
    from pathlib import Path

    import numpy as np
    from PIL import Image

    from mixcount.engine import render_passes as P
    from mixcount.engine import scene_build as B
    from mixcount.engine.mesh_cache import CACHE_DIR, cache_file
    from mixcount.worker.contract import SceneOutputs, SceneRequest

    out = Path(req["out_dir"])

    def load(mode: str) -> tuple[Any, dict[str, Any]]:
        request = SceneRequest.for_outputs(SceneOutputs.from_config(load_config().compose), stage=req["stage"],
                                           out_dir=str(out), threads=2, oracle=False)
        state = B.load_scene(dataclasses.replace(request, mesh_cache=mode))
        state.scene.render.resolution_percentage = 50
        ids = P.render_id_passes(state.scene, out / "_ids.exr")
        P.configure_rgb(state.scene, dataclasses.replace(state.spec.render, samples=2, denoise=False))
        P.render_to(state.scene, out / "_rgb.png")
        ids["rgb"] = np.asarray(Image.open(out / "_rgb.png"))
        events = next((d["assets"] for d in state.diagnostics if d["kind"] == "mesh_cache"), {})
        return state, {"ids": ids, "events": events}

    first, ref = load("off")
    assets = sorted(first.cache.meshes)
    lit = P.render_id_passes(first.scene, out / "_lit.exr", unlit=False)
    for a in assets:
        shutil.rmtree(Path(a).parent / CACHE_DIR, ignore_errors=True)
    runs = {"off": ref}
    _, runs["cold"] = load("zstd")
    _, runs["warm"] = load("zstd")
    broken = cache_file(Path(assets[0]))
    assert broken is not None
    broken.write_bytes(broken.read_bytes()[:4096])  # an interrupted copy, say
    _, runs["truncated"] = load("zstd")
    _, runs["after"] = load("zstd")
    blocked = cache_file(Path(assets[-1]))  # a folder where the file would go: the write must fail, not the scene
    assert blocked is not None
    blocked.unlink()
    blocked.mkdir()
    _, runs["unwritable"] = load("zstd")
    blocked.rmdir()
    keys = ("index", "depth", "normal", "rgb")
    return {"ok": True, "assets": [Path(a).name for a in assets], "broken": Path(assets[0]).name,
            "blocked": Path(assets[-1]).name,
            "events": {k: r["events"] for k, r in runs.items()},
            "equal": {k: all(np.array_equal(ref["ids"][x], r["ids"][x]) for x in keys) for k, r in runs.items()},
            "lit_equal": all(np.array_equal(lit[x], ref["ids"][x]) for x in ("index", "depth", "normal")),
            "files": sorted(p.name for d in {Path(a).parent / CACHE_DIR for a in assets} for p in d.glob("*.blend"))}


class _Left:
    def __init__(self) -> None:
        self.me = self
        self.data = b"\x01" * (300 << 20)  # resident: over the growth that makes a worker collect


_LEFT: list[Any] = []


def leave_cycle(req: dict[str, Any]) -> dict[str, Any]:
    import gc
    import weakref

    alive = sum(1 for r in _LEFT if r() is not None)
    left = _Left()
    _LEFT.append(weakref.ref(left))
    gc.collect(1)  # still referred to here: moved to the oldest generation, as a long request's objects are
    return {"ok": True, "alive": alive}


if __name__ == "__main__":
    sys.exit(worker_main.main({**worker_main.HANDLERS, "sleep": sleep, "canonical": canonical,
                               "leave_cycle": leave_cycle,
                                      "border_check": border_check, "rest_stop": rest_stop,
                                      "release_wave": release_wave, "mesh_cache": mesh_cache,
                                      "scaled_drop": scaled_drop}))
