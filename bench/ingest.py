"""Ingest throughput: first ingest vs unchanged rerun of ~200 generated objects.

Usage: .venv/bin/python bench/ingest.py [--objects 200] [--workers 2] [--subdivide 2] [--smoke]
       .venv/bin/python bench/ingest.py --pybullet [--pybullet-data DIR] [--workers 2]
Prints human lines to stderr and one JSON line to stdout at the end:
{"objects": N, "first_s": ..., "first_obj_per_s": ..., "rerun_s": ..., "rerun_obj_per_s": ..., "ratio": ...}
The rerun only hashes files and compares with the catalog (no mesh work), so the ratio should be >= 10.

The demo library's meshes are deliberately light (~100-2,500 faces); real captures have 10^4-10^6.
``--subdivide K`` (default 2: x16 faces, ~20k for a ball) makes the bench set capture-like by
subdividing every part K times (UVs and textures kept); ``--subdivide 0`` measures the demo meshes as
generated. Both figures are honest measurements; they answer different questions.

``--captures K``: cost at the paper's scale (issue 56). K capture-like DTC objects (``<name>/3d-asset.glb``:
a lumpy scan of ``--faces`` triangles, default 1.2 M, with a ``--texture-px`` JPEG, default 4096;
bench/big_meshes.py) through ingest, canonical render and filter, each step in a fresh process so its peak
memory is its own: seconds per object, peak RSS of one worker (the largest ingest worker / bpy worker /
filter process or the filter's parent), and the three extrapolated to 2,000 objects at ``--workers``. One JSON line:
{"bench": "ingest_captures", "objects": K, "faces": F, "texture_px": P, "steps": {"ingest": {"s_per_object": ...,
"peak_rss_mb_per_worker": ...}, "render": {...}, "filter": {...}}, "extrapolated_2000": {"hours": ...}}.
``--smoke`` with it: 2 objects of 20,000 faces, 256 px textures, 64 px renders (the suite runs it).
``--marginal`` with it: a second run of 2K objects, and per step what one more object costs (the slope, in
worker-s and CPU-s) and what every run costs (process and bpy starts, imports): a small run's per-object
average carries that fixed part and, with K not a multiple of the workers, an idle worker's tail, so the
2,000-object figure is fixed + 2,000 x slope (``"marginal"`` in the JSON line).

``--stages``: where one such object's seconds go (issue 69), in this process, one stage after another, CPU and
wall seconds each: ingest's hashing, its load (parse, whole-mesh facts, the reduced copy), geometry hash,
collision mesh and proxy; the filter's shape descriptor and surface samples; the canonical render's import,
its Cycles render and its albedo pass (bpy in this process, so last). One JSON line {"bench":
"ingest_stages", "stages": {name: {"cpu_s", "wall_s"}}, "peak_rss_mb": ...}. ``--smoke``: 20,000 faces.

``--pybullet``: real folders as they come (issue 52). 20 models of pybullet's own ``pybullet_data`` are
copied into folders named by a person (``Rubber duck/``, ``red_mug/``, ``blue_mug/``), each with what the
package ships beside the model (.mtl or none, textures, the URDF, collision companions), then ingested
twice. Prints one JSON line: objects, broken, named by their folder, companions taken for objects, the
up axis and its reason per object, dims, flags, and the second run's figures. ``pybullet_data`` is found
(:func:`find_pybullet_data`) from ``--pybullet-data``, ``MIXCOUNT_PYBULLET_DATA``, an installed
``pybullet_data`` package, or a pybullet wheel in ``MIXCOUNT_WHEELS`` / ``~/.cache/mixcount/wheels`` /
``/work/cache/wheels`` (``pip download --no-deps pybullet==3.2.7 -d DIR`` fetches one); without it the bench
prints ``{"skipped": reason}`` and exits 0.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mixcount.catalog.db import open_catalog  # noqa: E402
from mixcount.catalog.ingest import ingest_paths  # noqa: E402
from mixcount.config import load_config  # noqa: E402
from mixcount.demo.library import generate_demo_library  # noqa: E402


def stage_timed(stages: dict[str, dict[str, float]], name: str, fn: Any, *a: Any, **k: Any) -> Any:
    """``fn(*a, **k)`` with this process's CPU seconds and wall seconds recorded as ``stages[name]``."""
    import resource

    r0, w0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    out = fn(*a, **k)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    stages[name] = {"cpu_s": round(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, 2),
                    "wall_s": round(time.perf_counter() - w0, 2)}
    return out


def densify(lib: Path, times: int) -> None:
    """Subdivide every part of every readable GLB in ``lib`` ``times`` times (capture-like density)."""
    import trimesh

    for glb in sorted(lib.glob("*/3d-asset.glb")):
        try:
            scene = trimesh.load(glb, force="scene")
        except Exception:
            continue  # the planted broken files stay broken
        for key, geom in list(scene.geometry.items()):
            for _ in range(times):
                geom = geom.subdivide()
            scene.geometry[key] = geom
        glb.write_bytes(scene.export(file_type="glb"))


# person-named folder -> files copied from pybullet_data (the model, what ships beside it)
PYBULLET_FOLDERS = {
    "Rubber duck": ["duck.obj", "duck.mtl", "duckCM.png", "duck_vhacd.obj", "duck_vhacd.urdf"],
    "Serving tray": ["tray/tray_textured4.obj", "tray/tray_textured4.mtl", "tray/tray.jpg", "tray/tray.urdf"],
    "Sugar cube": ["cube.obj", "cube.urdf", "cube.png"],  # cube.obj names a cube.mtl the package lacks
    "Jenga block": ["jenga/jenga.obj", "jenga/jenga.mtl", "jenga/jenga.png", "jenga/jenga.urdf"],
    "red_mug": ["objects/mug.obj", "objects/mug_col.obj", "objects/mug.urdf"],
    "blue_mug": ["urdf/mug.obj", "urdf/mug_col.obj", "urdf/mug.urdf"],
    "Teddy bear": ["teddy2_VHACD_CHs.obj", "teddy_vhacd.urdf"],
    "Soccer ball": ["soccerball.obj", "soccerball.mtl", "colors16.png", "soccerball.urdf"],
    "Bunny": ["bunny.obj"],
    "Table": ["table/table.obj", "table/table.mtl", "table/table.png", "table/table.urdf"],
    "Small sphere": ["textured_sphere_smooth.obj", "textured_sphere_smooth.mtl", "checker_huge.gif",
                     "sphere_small.urdf"],
    "Gripper finger": ["l_finger.stl", "l_finger_collision.stl"],
    "Stone": ["stone.obj", "stone.mtl"],
    "Domino": ["domino/domino.obj", "domino/domino.mtl", "domino/domino.jpg", "domino/domino.urdf"],
    "Lego brick": ["lego/lego.obj", "lego/lego_vhacd.obj", "lego/lego.urdf"],
    "Torus": ["torus/torus_textured.obj", "torus/torus_textured.mtl", "cube.png"],  # its .mtl says ../cube.png
    "Toy box": ["toys/concave_box.obj", "toys/concave_box.mtl", "toys/concave_box.urdf", "checker_grid.jpg"],
    "Random shape": ["random_urdfs/000/000.obj", "random_urdfs/000/000.mtl", "random_urdfs/000/000.urdf"],
    # its .mtl names E:\\develop\\bullet3\\data\\table\\table.png; the user copied table.png beside it
    "Shape sorter": ["toys/shape_sorter.obj", "toys/shape_sorter.mtl", "table/table.png"],
    "Square table": ["table_square/table.obj", "table_square/table.mtl", "table_square/checker_grid.jpg",
                     "table_square/table_square.urdf"],
}
PYBULLET_COMPANIONS = ("duck_vhacd.obj", "mug_col.obj", "l_finger_collision.stl", "lego_vhacd.obj")


def find_pybullet_data(given: str | None, unpack_to: Path) -> tuple[Path | None, str]:
    """(the pybullet_data folder, where it came from) or (None, why not)."""
    import os
    import zipfile

    for where in (given, os.environ.get("MIXCOUNT_PYBULLET_DATA")):
        if where:
            path = Path(where).expanduser()
            return (path, str(path)) if (path / "duck.obj").is_file() else (None, f"{path} holds no duck.obj")
    try:
        import pybullet_data  # type: ignore[import-not-found]

        return Path(pybullet_data.getDataPath()), "installed pybullet_data"
    except ImportError:
        pass
    dirs = [os.environ.get("MIXCOUNT_WHEELS"), str(Path.home() / ".cache" / "mixcount" / "wheels"), "/work/cache/wheels"]
    for d in filter(None, dirs):
        for wheel in sorted(Path(d).glob("pybullet-*.whl")):
            with zipfile.ZipFile(wheel) as zf:
                zf.extractall(unpack_to, [n for n in zf.namelist() if n.startswith("pybullet_data/")])
            return unpack_to / "pybullet_data", str(wheel)
    return None, ("no pybullet_data: give --pybullet-data DIR or MIXCOUNT_PYBULLET_DATA, or put a pybullet wheel "
                  "in MIXCOUNT_WHEELS (pip download --no-deps pybullet==3.2.7 -d DIR)")


def build_pybullet_folders(data: Path, root: Path) -> Path:
    """Copy :data:`PYBULLET_FOLDERS` out of ``data`` the way a user would: one folder per object."""
    import shutil

    for folder, files in PYBULLET_FOLDERS.items():
        (root / folder).mkdir(parents=True, exist_ok=True)
        for rel in files:
            shutil.copy2(data / rel, root / folder / Path(rel).name)
    return root


def run_pybullet(args: argparse.Namespace) -> int:
    from sqlalchemy import select

    from mixcount.catalog.models import CatalogObject, Flag

    config = load_config(values={"ingest.workers": args.workers})
    with tempfile.TemporaryDirectory(prefix="mixcount-pybullet-") as tmp:
        root = Path(tmp)
        data, origin = find_pybullet_data(args.pybullet_data, root / "unpacked")
        if data is None:
            print(json.dumps({"skipped": origin}))
            return 0
        lib = build_pybullet_folders(data, root / "My models")
        catalog = open_catalog(str(root / "bench.db"), data_dir="")
        try:
            t0 = time.perf_counter()
            first = ingest_paths(catalog, [lib], config=config)
            first_s = time.perf_counter() - t0
            second = ingest_paths(catalog, [lib], config=config)
            with catalog.session() as s:
                objs = s.scalars(select(CatalogObject).order_by(CatalogObject.name)).all()
                rows = []
                for o in objs:
                    info = json.loads(o.metadata_json or "{}").get("ingest", {})
                    kinds = sorted(f.kind for f in s.scalars(select(Flag).where(Flag.object_id == o.id)))
                    rows.append({"name": o.name, "category": o.category, "status": o.status, "error": o.error,
                                 "file": Path(o.model_path).name, "up_axis": o.source_up_axis,
                                 "up_axis_reason": info.get("up_axis_reason"), "units": o.source_units,
                                 "dims_m": [round(d, 4) for d in o.dims] if o.dim_x is not None else None,
                                 "flags": kinds, "warnings": info.get("warnings") or [],
                                 "collision_companion": bool(info.get("collision_source"))})
        finally:
            catalog.close()
    result = {
        "source": origin, "folders": len(PYBULLET_FOLDERS), "objects": len(rows), "broken": first.broken,
        "named_by_folder": sum(r["name"] in PYBULLET_FOLDERS for r in rows),
        "companions_as_objects": sum(r["file"] in PYBULLET_COMPANIONS for r in rows),
        "collision_companions_used": sum(r["collision_companion"] for r in rows),
        "up_axis": {a: sum(r["up_axis"] == a for r in rows) for a in ("X", "Y", "Z")},
        "warnings": len(first.warnings), "first_s": round(first_s, 2),
        "second": {"new": second.new, "updated": second.updated, "unchanged": second.unchanged,
                   "broken": second.broken, "reoriented": len(second.reoriented)},
        "objects_detail": rows,
    }
    for r in rows:
        print(f"{r['name']:<14} {r['category']:<8} up {r['up_axis']} ({r['up_axis_reason']}) dims {r['dims_m']} "
              f"units {r['units']} flags {r['flags']}", file=sys.stderr)
    print(json.dumps(result))
    return 0


def _step(step: str, db: str, workers: int, values: dict) -> dict:
    """One step of ``--captures`` in a fresh process: wall seconds and the peak RSS of its largest worker."""
    import subprocess

    cmd = [sys.executable, __file__, "--captures-step", step, "--captures-db", db, "--workers", str(workers),
           "--captures-set", json.dumps(values)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"captures step {step} failed:\n{proc.stderr[-2000:]}")
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "wall_s": round(wall, 2)}


def run_captures_step(args: argparse.Namespace) -> int:
    """Inside the step's process: run it, print {"peak_rss_mb_per_worker", "detail"} (workers' RSS from
    RUSAGE_CHILDREN: the largest child; the process's own when the step runs in it)."""
    import resource

    values = json.loads(args.captures_set)
    config = load_config(values={"ingest.workers": args.workers, "canonical_render.workers": args.workers,
                                 "filter.workers": args.workers,
                                 **{k: v for k, v in values.items() if not k.startswith("_")}})
    catalog = open_catalog(args.captures_db, data_dir="")
    try:
        if args.captures_step == "ingest":
            detail = ingest_paths(catalog, [Path(values.get("_lib", ""))], config=config).as_dict()
        elif args.captures_step == "render":
            from mixcount.curation.renders import render_catalog

            detail = render_catalog(catalog, config.canonical_render).as_dict()
        else:
            from mixcount.curation.finding.catalog_filter import run_filter

            res = run_filter(catalog, config)
            detail = {"objects": res.objects, "flags": res.flags}
    finally:
        catalog.close()
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    cpu = sum(u.ru_utime + u.ru_stime for u in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))
    # the filter's parent holds the catalog and every gathered figure: its own peak counts as a worker's
    worker = max(kids, own) if args.captures_step == "filter" else (kids if kids > 0 else own)
    print(json.dumps({"peak_rss_mb_per_worker": round(worker, 1), "parent_rss_mb": round(own, 1), "cpu_s": round(cpu, 2),
                      "detail": {k: v for k, v in detail.items() if k in ("new", "broken", "broken_objects", "warnings",
                                                                       "rendered", "failed", "failures", "objects",
                                                                       "flags")}}))
    return 0


def run_stages(args: argparse.Namespace) -> int:
    """``--stages``: one capture-like object through each stage in this process (docstring above)."""
    import resource

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import big_meshes as B

    from mixcount.catalog import hashing
    from mixcount.catalog.mesh import build_collision_mesh, geometry_hash, load_normalised
    from mixcount.catalog.proxies import proxy_from_collision
    from mixcount.curation.finding import appearance3d as A
    from mixcount.curation.finding import descriptors as D

    faces, px = (20_000, 256) if args.smoke else (args.faces, args.texture_px)
    config = load_config(values={"canonical_render.resolution": 64 if args.smoke else 512,
                                 "canonical_render.samples": 2 if args.smoke else 16})
    stages: dict[str, dict[str, float]] = {}

    def timed(name: str, fn: Any, *a: Any, **k: Any) -> Any:
        out = stage_timed(stages, name, fn, *a, **k)
        print(f"{name}: {stages[name]}", file=sys.stderr)
        return out

    with tempfile.TemporaryDirectory(prefix="mixcount-stages-") as tmp:
        glb = Path(tmp) / "3d-asset.glb"
        verts, tris, uv = B.lumpy_grid(faces, seed=0, radius=0.04)
        B.write_textured_glb(glb, verts, tris, uv, px, seed=0)
        del verts, tris, uv
        ing = config.ingest
        timed("ingest: hashing", hashing.files_hash, {"model.glb": glb})
        norm = timed("ingest: load, whole-mesh facts, reduced copy", load_normalised, glb, units="m", up_axis="Y",
                     face_budget=ing.facts_face_budget)
        ghash = timed("ingest: geometry hash", geometry_hash, norm.mesh)
        col = Path(tmp) / "col" / f"{ghash[:32]}_{ing.collision_face_budget}.ply"
        timed("ingest: collision mesh", build_collision_mesh, norm.mesh, col, ing.collision_face_budget)
        timed("ingest: proxy", proxy_from_collision, col, ghash, col.parent, ing.proxy_max_vertices)
        del norm
        timed("filter: shape descriptor", D.load_shape, str(glb), units="m", up_axis="Y", cache_dir=None, key=None)
        timed("filter: surface samples", A.load_samples, str(glb), cache_dir=None, key=None)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        # bpy in a child: it fails to load beside pymeshlab's own Embree (undefined symbol rtcGetSceneTraversable)
        import subprocess

        cmd = [sys.executable, __file__, "--stages-render", str(glb)] + (["--smoke"] if args.smoke else [])
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"render stages failed:\n{proc.stderr[-2000:]}")
        child = json.loads(proc.stdout.strip().splitlines()[-1])
        stages.update(child["stages"])
        print("\n".join(f"{k}: {v}" for k, v in child["stages"].items()), file=sys.stderr)
    print(json.dumps({"bench": "ingest_stages", "faces": faces, "texture_px": px, "stages": stages,
                      "peak_rss_mb": round(peak, 1), "render_peak_rss_mb": child["peak_rss_mb"]}))
    return 0


def run_render_stages(args: argparse.Namespace) -> int:
    """``--stages``' child: the canonical render of one model with 1 Cycles thread (as each of 2 workers on
    2 cores), its import and albedo timed apart (a light model's second render, ``render_albedo``; a heavy
    one's passes of its one render, ``save_colour_passes`` + ``write_albedo``); the rest of the whole is
    the Cycles render itself. bpy is imported as a worker of 2 imports it (TBB sized to its 1 thread)."""
    from mixcount.engine.worker_main import import_bpy

    import_bpy(1)
    from mixcount.engine import canonical_render as C
    from mixcount.worker.canonical_contract import CanonicalRequest, CanonicalSettings

    config = load_config(values={"canonical_render.resolution": 64 if args.smoke else 512,
                                 "canonical_render.samples": 2 if args.smoke else 16})
    glb = Path(args.stages_render)
    req = CanonicalRequest(model_path=str(glb), out_dir=str(glb.parent / "render"), stem="x", threads=1,
                           settings=CanonicalSettings.from_config(config.canonical_render), up_axis="Y")
    stages: dict[str, dict[str, float]] = {}

    def timed(name: str, fn: Any, *a: Any, **k: Any) -> Any:
        return stage_timed(stages, name, fn, *a, **k)

    # the light path's second render (render_albedo), or the heavy path's passes of the one render
    for name in ("import_model", "render_albedo", "save_colour_passes", "write_albedo"):
        setattr(C, name, (lambda n, f: lambda *a, **k: timed(f"render: {n}", f, *a, **k))(name, getattr(C, name)))
    timed("render: whole (1 thread)", C.render_object, req)
    # VmHWM: this process's own peak (ru_maxrss keeps the forking parent's across exec)
    hwm = next(int(line.split()[1]) for line in Path("/proc/self/status").read_text().splitlines()
               if line.startswith("VmHWM:"))
    print(json.dumps({"stages": stages, "peak_rss_mb": round(hwm / 1024, 1)}))
    return 0


def captures_once(args: argparse.Namespace, k: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """``k`` capture-like objects through ingest, render and filter, each step in a fresh process: the steps'
    figures (with per-object worker-s and CPU-s), and what was measured (faces, texture, render settings)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import big_meshes as B

    faces, px = args.faces, args.texture_px
    render = {"canonical_render.resolution": 512, "canonical_render.samples": 16}
    if args.smoke:
        faces, px = 20_000, 256
        render = {"canonical_render.resolution": 64, "canonical_render.samples": 2}
    with tempfile.TemporaryDirectory(prefix="mixcount-captures-") as tmp:
        lib = Path(tmp) / "lib"
        t0 = time.perf_counter()
        for i in range(k):
            verts, tris, uv = B.lumpy_grid(faces, seed=i, radius=0.04 + 0.01 * (i % 3))
            (lib / f"Capture_{i:04d}").mkdir(parents=True)
            B.write_textured_glb(lib / f"Capture_{i:04d}" / "3d-asset.glb", verts, tris, uv, px, seed=i)
        n_faces = int(len(tris))
        print(f"generated {k} objects of {n_faces} faces, {px} px textures in {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)
        db = str(Path(tmp) / "bench.db")
        values = {"_lib": str(lib), **render, **json.loads(args.captures_set)}
        steps = {name: _step(name, db, args.workers, values) for name in ("ingest", "render", "filter")}
    for name, st in steps.items():
        # worker-seconds per object: a step's wall time x the processes it kept busy, over the objects
        # (the filter's descriptors and pair figures run in filter.workers processes too)
        st["busy_workers"] = min(args.workers, k)
        st["s_per_object"] = round(st["wall_s"] * st["busy_workers"] / k, 2)
        st["cpu_s_per_object"] = round(st["cpu_s"] / k, 2)  # steadier than wall on a loaded machine
        print(f"{name}: {st['wall_s']} s for {k} objects ({st['s_per_object']} worker-s, {st['cpu_s_per_object']} "
              f"CPU-s per object), peak "
              f"{st['peak_rss_mb_per_worker']} MB per worker", file=sys.stderr)
    return steps, {"faces": n_faces, "texture_px": px, "render": {k2.split(".")[1]: v for k2, v in render.items()}}


def marginal(small: dict[str, Any], big: dict[str, Any], k_small: int, k_big: int) -> dict[str, Any]:
    """Per step, what one more object costs (the slope between a run of ``k_small`` and one of ``k_big``
    objects) and what a run costs whatever its size (the intercept: process starts, imports, bpy starts,
    the catalog's own queries), in worker-s (wall x busy workers) and CPU-s. A run of K objects then costs
    fixed + K x per_object: the figure that scales to 2,000, where the per-object averages of a small run
    also carry its fixed part and, with K not a multiple of the workers, an idle worker's tail."""
    out: dict[str, Any] = {}
    for name in small:
        a, b = small[name], big[name]
        ws_a, ws_b = a["wall_s"] * a["busy_workers"], b["wall_s"] * b["busy_workers"]
        per_ws = (ws_b - ws_a) / (k_big - k_small)
        per_cpu = (b["cpu_s"] - a["cpu_s"]) / (k_big - k_small)
        out[name] = {"worker_s_per_object": round(per_ws, 2), "cpu_s_per_object": round(per_cpu, 2),
                     "fixed_worker_s": round(ws_a - k_small * per_ws, 1), "fixed_cpu_s": round(a["cpu_s"] - k_small * per_cpu, 1),
                     "peak_rss_mb_per_worker": max(a["peak_rss_mb_per_worker"], b["peak_rss_mb_per_worker"])}
    return out


def run_captures(args: argparse.Namespace) -> int:
    k = 2 if args.smoke else args.captures
    steps, what = captures_once(args, k)
    per_obj = sum(st["s_per_object"] for st in steps.values())
    hours = 2000 * per_obj / 3600.0
    result = {
        "bench": "ingest_captures", "objects": k, **what, "workers": args.workers,
        "steps": steps,
        "extrapolated_2000": {"worker_hours": round(hours, 2),
                              "cpu_hours_at_workers": round(2000 * sum(st["cpu_s_per_object"] for st in steps.values())
                                                            / 3600.0 / args.workers, 2), "hours_at_workers": round(hours / args.workers, 2),
                              "peak_rss_mb_per_worker": max(st["peak_rss_mb_per_worker"] for st in steps.values()),
                              "by_step_hours": {n: round(2000 * st["s_per_object"] / 3600.0 / args.workers, 2)
                                                for n, st in steps.items()}},
    }
    failed = broken_or_failed(steps)
    if args.marginal and not args.smoke:
        big, _ = captures_once(args, 2 * k)
        slope = marginal(steps, big, k, 2 * k)
        ws = sum(v["worker_s_per_object"] for v in slope.values())
        cpu = sum(v["cpu_s_per_object"] for v in slope.values())
        fixed_ws = sum(v["fixed_worker_s"] for v in slope.values())
        result["objects_second_run"] = 2 * k
        result["steps_second_run"] = big
        result["marginal"] = {"steps": slope, "worker_s_per_object": round(ws, 2), "cpu_s_per_object": round(cpu, 2),
                              "fixed_worker_s": round(fixed_ws, 1),
                              "hours_2000_at_workers": round((fixed_ws + 2000 * ws) / 3600.0 / args.workers, 2),
                              "cpu_hours_2000_at_workers": round((sum(v["fixed_cpu_s"] for v in slope.values())
                                                                  + 2000 * cpu) / 3600.0 / args.workers, 2)}
        print(f"marginal, {k} -> {2 * k} objects: {ws:.2f} worker-s and {cpu:.2f} CPU-s per object "
              f"(fixed {fixed_ws:.0f} worker-s a run); 2,000 objects at {args.workers} workers: "
              f"{result['marginal']['hours_2000_at_workers']} h", file=sys.stderr)
        failed = failed or broken_or_failed(big)
    print(json.dumps(result))
    return 1 if failed else 0


def broken_or_failed(steps: dict[str, Any]) -> bool:
    """A run whose ingest recorded a broken object or whose render failed one: its figures are not the cost."""
    return bool(steps["ingest"]["detail"].get("broken", 0) or steps["render"]["detail"].get("failed", 0))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pybullet", action="store_true", help="ingest 20 pybullet_data models in person-named folders")
    parser.add_argument("--pybullet-data", default=None, help="an unpacked pybullet_data folder")
    parser.add_argument("--objects", type=int, default=200, help="about this many objects (whole demo libraries of 79)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--subdivide", type=int, default=2, help="subdivide every part K times (x4^K faces)")
    parser.add_argument("--smoke", action="store_true",
                        help="seconds: one demo library as generated; exit 0 whatever the ratio (the suite runs it)")
    parser.add_argument("--captures", type=int, default=0, help="K capture-like DTC objects through ingest, render, filter")
    parser.add_argument("--faces", type=int, default=1_200_000, help="--captures: faces per object")
    parser.add_argument("--texture-px", type=int, default=4096, help="--captures: texture side in pixels")
    parser.add_argument("--marginal", action="store_true",
                        help="--captures K: also run 2K objects and report what one more object costs (the slope) "
                             "and the run's fixed part: the 2,000-object extrapolation")
    parser.add_argument("--stages", action="store_true", help="one capture-like object, seconds per stage")
    parser.add_argument("--stages-render", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--captures-step", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--captures-db", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--captures-set", default="{}",
                        help='--captures: config values as JSON for every step, e.g. \'{"canonical_render.heavy_faces": 100000000}\' '
                             "(the light render path for an A/B)")
    args = parser.parse_args()
    if args.captures_step:
        return run_captures_step(args)
    if args.stages_render:
        return run_render_stages(args)
    if args.stages:
        return run_stages(args)
    if args.captures:
        return run_captures(args)
    if args.pybullet:
        return run_pybullet(args)
    if args.smoke:
        args.objects, args.subdivide = 1, 0
    config = load_config(values={"ingest.workers": args.workers})
    with tempfile.TemporaryDirectory(prefix="mixcount-bench-") as tmp:
        root = Path(tmp)
        libs, total, seed = [], 0, 0
        t0 = time.perf_counter()
        while total < args.objects:
            lib = root / f"lib{seed}"
            truth = generate_demo_library(lib, seed=100 + seed)
            if args.subdivide:
                densify(lib, args.subdivide)
            libs.append(lib)
            total += truth["expected"]["total"]
            seed += 1
        gen_s = time.perf_counter() - t0
        print(f"generated {total} objects in {len(libs)} libraries in {gen_s:.1f} s", file=sys.stderr)
        catalog = open_catalog(str(root / "bench.db"), data_dir="")
        try:
            t0 = time.perf_counter()
            first = ingest_paths(catalog, libs, config=config)
            first_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            rerun = ingest_paths(catalog, libs, config=config)
            rerun_s = time.perf_counter() - t0
        finally:
            catalog.close()
    assert rerun.new == rerun.updated == 0 and rerun.unchanged == first.new, rerun.as_dict()
    result = {
        "objects": first.total, "workers": args.workers, "subdivide": args.subdivide, "new": first.new, "broken": first.broken,
        "first_s": round(first_s, 3), "first_obj_per_s": round(first.total / first_s, 1),
        "rerun_s": round(rerun_s, 3), "rerun_obj_per_s": round(rerun.total / rerun_s, 1),
        "ratio": round(first_s / rerun_s, 1),
    }
    print(f"first ingest: {result['first_obj_per_s']} objects/s; unchanged rerun: {result['rerun_obj_per_s']} "
          f"objects/s; {result['ratio']}x", file=sys.stderr)
    print(json.dumps(result))
    return 0 if args.smoke or result["ratio"] >= 10 else 1


if __name__ == "__main__":
    sys.exit(main())
