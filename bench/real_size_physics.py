"""Physics per size band in the real-size rule (issue 70): bodies lost and the worst interpenetration.

    .venv/bin/python bench/real_size_physics.py --work W              # 4 bands + 2 mixed + the paper, 2 seeds each
    .venv/bin/python bench/real_size_physics.py --work W --seeds 3 --n 40-60
    .venv/bin/python bench/real_size_physics.py --smoke               # one band, one small scene

Per band a small library of parts is written (a cylinder like a radial capacitor and a box like an IC, their
sizes stated in metadata.json: the band's size and 0.6 x it, and a tray 12 x 8 x 1.5 band sizes as the
container), ingested into its own catalog (every object in train), and composed end to end by the worker
with ``scene.size_rule = "real"`` (default physics: 300 frames, 8 substeps, convex hulls) at 32 px and 1
sample, every other scene in the tray: bands 2 mm, 2 cm, 20 cm, 50 cm; two mixed libraries (2 mm parts beside 2 cm ones, 2 cm beside 50 cm:
one scale per scene, so the small class is at the paper's smallest and the large one 10 or 25 x it); and the
2 cm library under the paper's rule as the baseline of today's settling.

From each scene's metadata.json: counted bodies spawned, lost (below_floor, flung_out, unstable), dropped for
interpenetration, and the worst interpenetration among the bodies the scene keeps: the deepest
vertex of one body's collision hull inside another's (both hulls from the catalog's collision meshes at
their settled poses), as a share of the smaller body's size; and the deepest point under the floor's top
(min_z) as a share of the body's size. stdout: one JSON line; stderr: a table.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

BANDS: dict[str, list[float]] = {"2 mm": [0.002], "2 cm": [0.02], "20 cm": [0.2], "50 cm": [0.5],
                                 "2 mm + 2 cm": [0.002, 0.02], "2 cm + 50 cm": [0.02, 0.5]}
LOST = ("below_floor", "flung_out", "unstable")


def write_library(root: Path, sizes: list[float]) -> Path:
    """Per size a cylinder part (largest side = size) and a box part (0.6 x size), and one tray for the largest."""
    import trimesh

    for size in sizes:
        tag = f"{size * 1000:g}mm"
        parts = {f"Capacitor {tag}": (trimesh.creation.cylinder(radius=0.3, height=1.0, sections=16), size, (0.1, 0.3, 0.8)),
                 f"Chip {tag}": (trimesh.creation.box(extents=(1.0, 0.65, 0.35)), 0.6 * size, (0.15, 0.15, 0.15))}
        for name, (mesh, real, colour) in parts.items():
            folder = root / name
            folder.mkdir(parents=True, exist_ok=True)
            mesh.visual.face_colors = [int(255 * c) for c in colour] + [255]
            mesh.export(folder / "model.glb")
            (folder / "metadata.json").write_text(json.dumps({"size": f"{real * 1000:g} mm", "category": name.split()[0].lower()}))
    big = max(sizes)
    tray = root / "Parts tray"
    tray.mkdir(parents=True, exist_ok=True)
    base = trimesh.creation.box(extents=(12.0, 8.0, 0.3))
    walls = [trimesh.creation.box(extents=e).apply_translation(t) for e, t in (
        ((12.0, 0.3, 1.5), (0, 3.85, 0.6)), ((12.0, 0.3, 1.5), (0, -3.85, 0.6)),
        ((0.3, 8.0, 1.5), (5.85, 0, 0.6)), ((0.3, 8.0, 1.5), (-5.85, 0, 0.6)))]
    mesh = trimesh.util.concatenate([base, *walls])
    mesh.visual.face_colors = [200, 200, 190, 255]
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # Y-up GLB, opening up
    mesh.export(tray / "model.glb")
    (tray / "metadata.json").write_text(json.dumps({"size": f"{12 * big * 1000:g} mm", "category": "tray"}))
    return root


def catalog_for(work: Path, name: str, sizes: list[float]) -> Path:
    from sqlalchemy import select

    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject, Split
    from mixcount.cli import main

    folder = work / name.replace(" ", "").replace("+", "_")
    db = folder / "catalog.db"
    if db.exists():
        return db
    lib = write_library(folder / "lib", sizes)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["--db", str(db), "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    cat = open_catalog(str(db), data_dir="")
    with cat.session() as s:
        for obj in s.scalars(select(CatalogObject)):
            s.add(Split(object_id=obj.id, split="train", method="random"))
        s.commit()
    cat.close()
    return db


def hull_of(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(hull vertices, hull plane equations) of a collision mesh, in its own (asset) metres."""
    import trimesh
    from scipy.spatial import ConvexHull

    v = np.asarray(trimesh.load(path, force="mesh").vertices, dtype=np.float64)
    h = ConvexHull(v)
    return v[h.vertices], h.equations


def worst_overlap(bodies: list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]) -> float:
    """The deepest vertex of one kept body's hull inside another's, as a share of the smaller size."""
    worst = 0.0
    world = []
    for verts, _eqs, m, _size in bodies:
        w = verts @ m[:3, :3].T + m[:3, 3]
        world.append((w, w.min(axis=0), w.max(axis=0)))
    for i, (wa, lo_a, hi_a) in enumerate(world):
        for j, (_wb, lo_b, hi_b) in enumerate(world):
            if i == j or np.any(hi_a < lo_b) or np.any(hi_b < lo_a):
                continue
            inv = np.linalg.inv(bodies[j][2])
            scale = float(np.cbrt(abs(np.linalg.det(bodies[j][2][:3, :3]))))
            local = wa @ inv[:3, :3].T + inv[:3, 3]
            depth = -(local @ bodies[j][1][:, :3].T + bodies[j][1][:, 3]).max(axis=1) * scale
            worst = max(worst, float(depth.max()) / min(bodies[i][3], bodies[j][3]))
    return worst


def scene_figures(scene: Path, hulls: dict[int, tuple[np.ndarray, np.ndarray]]) -> dict[str, Any]:
    meta = json.loads((scene / "metadata.json").read_text())
    counted = [o for o in meta["objects"] if o["role"] == "counted"]
    # the bodies the dataset keeps (a body dropped later, occluded or outside the frame, is moved away by the
    # worker: its recorded pose is not where it settled)
    settled = [o for o in counted if o["status"] == "kept" and o.get("matrix_world")]
    bodies = [(*hulls[o["object_id"]], np.asarray(o["matrix_world"], dtype=np.float64), float(o["size_m"]))
              for o in settled]
    sink = max([max(0.0, -float(o["min_z"])) / float(o["size_m"]) for o in settled if o.get("min_z") is not None] or [0.0])
    return {"scene": meta["scene_id"], "scale": meta["spec"]["scale"], "container": meta["spec"]["container"] is not None,
            "spawned": len(counted), "lost": sum(o.get("reason") in LOST for o in counted),
            "interpenetration_drops": sum(o.get("reason") == "interpenetration" for o in counted),
            "kept": sum(o["status"] == "kept" for o in counted), "worst_overlap": round(worst_overlap(bodies), 4),
            "worst_floor_sink": round(sink, 4), "physics_s": round(float(meta["timings"].get("worker.physics", 0.0)), 2)}


def run_band(work: Path, name: str, sizes: list[float], rule: str, seeds: list[int], n: str,
             resolution: int) -> list[dict[str, Any]]:
    from sqlalchemy import select

    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject
    from mixcount.cli import main

    db = catalog_for(work, name, sizes)
    cat = open_catalog(str(db), data_dir="")
    with cat.session() as s:
        hulls = {int(o.id): hull_of(o.collision_path) for o in s.scalars(select(CatalogObject)) if o.collision_path}
    cat.close()
    out = work / "out" / f"{name.replace(' ', '').replace('+', '_')}_{rule}"
    rows = []
    for k, seed in enumerate(seeds):  # every other scene in the band's tray (its own dataset: other settings)
        args = ["--db", str(db), "--set", f'scene.size_rule="{rule}"', "--set", f"scene.n_objects=[{n.replace('-', ',')}]",
                "--set", "scene.n_classes=[2,2]", "--set", "scene.n_distractors=[0,0]",
                "--set", 'scene.counted_exclude_categories=["tray"]',
                "--set", f"scene.no_container_probability={1.0 if k % 2 == 0 else 0.0}", "compose", "--n", "1", "--split", "train",
                "--seed", str(seed), "--resolution", str(resolution), "--samples", "1", "--out", str(out / f"tray{k % 2}")]
        scenes = out / f"tray{k % 2}" / "scenes"
        before = set(scenes.glob("scene_*")) if scenes.is_dir() else set()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
            code = main(args)
        if code != 0:
            rows.append({"band": name, "rule": rule, "seed": seed, "error": err.getvalue()[-400:]})
            continue
        for scene in sorted(set(scenes.glob("scene_*")) - before):
            rows.append({"band": name, "rule": rule, "seed": seed, "wall_s": round(time.perf_counter() - t0, 1),
                         **scene_figures(scene, hulls)})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=None, help="work folder (default: a temporary one)")
    ap.add_argument("--seeds", type=int, default=2, help="scenes per band (the odd ones in the band's tray)")
    ap.add_argument("--n", default="30-50", help="counted bodies spawned per scene, low-high")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--bands", default="", help="only these bands, comma-separated (e.g. '2 cm + 50 cm,2 mm')")
    ap.add_argument("--smoke", action="store_true", help="one band, one scene of 8-10 bodies")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="real_size_physics_"))
    work.mkdir(parents=True, exist_ok=True)
    runs: list[tuple[str, str]] = [(b, "real") for b in BANDS] + [("2 cm", "paper")]
    if a.bands:
        runs = [r for r in runs if r[0] in a.bands.split(",")]
    seeds, n = list(range(a.seeds)), a.n
    if a.smoke:
        runs, seeds, n = [("2 mm", "real")], [0], "8-10"
    rows = []
    for band, rule in runs:
        rows += run_band(work, band, BANDS[band], rule, seeds, n, a.resolution)
    summary = []
    for band, rule in runs:
        mine = [r for r in rows if r["band"] == band and r["rule"] == rule and "error" not in r]
        summary.append({"band": band, "rule": rule, "scenes": len(mine), "spawned": sum(r["spawned"] for r in mine),
                        "lost": sum(r["lost"] for r in mine),
                        "interpenetration_drops": sum(r["interpenetration_drops"] for r in mine),
                        "kept": sum(r["kept"] for r in mine),
                        "worst_overlap": max([r["worst_overlap"] for r in mine] or [0.0]),
                        "worst_floor_sink": max([r["worst_floor_sink"] for r in mine] or [0.0]),
                        "scales": sorted({r["scale"] for r in mine}),
                        "errors": sum(1 for r in rows if r["band"] == band and r["rule"] == rule and "error" in r)})
    print(f"{'band':<14}{'rule':<7}{'scenes':>7}{'spawned':>8}{'lost':>6}{'interp.':>8}{'kept':>6}"
          f"{'worst overlap':>15}{'floor sink':>12}  scales", file=sys.stderr)
    for s in summary:
        print(f"{s['band']:<14}{s['rule']:<7}{s['scenes']:>7}{s['spawned']:>8}{s['lost']:>6}{s['interpenetration_drops']:>8}"
              f"{s['kept']:>6}{s['worst_overlap']:>15.3f}{s['worst_floor_sink']:>12.3f}  {s['scales']}", file=sys.stderr)
    print(json.dumps({"bench": "real_size_physics", "summary": summary, "scenes": rows}, sort_keys=True))


if __name__ == "__main__":
    main()
