"""Mesh facts within bounds (issue 60): a model above ``ingest.facts_face_budget`` faces is measured whole
where that is cheap (box, area, volume, watertightness, counts) and hashed / collided on a reduced copy,
and says so; absurd coordinates (1e30, inf, nan) make a model broken with the reason, with nothing on stderr.

Real files from public packages (tests/public_packages.py): the reduced path must give the facts the
whole-mesh path gives. The rule was written against PrusaSlicer's bunny and torus and glmark2's bunny (here:
the torus); the other files (assimp's test models, PrusaSlicer's other shapes) were not looked at while writing it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from public_packages import deb_tree
from sqlalchemy import select

from mixcount.catalog.mesh import analyse_model
from mixcount.catalog.mesh_bounds import ABSURD_M
from mixcount.errors import IngestError

FACTS = ("face_count", "vertex_count", "watertight", "dim_x", "dim_y", "dim_z", "area", "volume")
# (package, path under usr/share): tuning files first, then held-out ones
REAL = [("prusa-slicer", "PrusaSlicer/shapes/torus.stl"),
        ("prusa-slicer", "PrusaSlicer/shapes/M3x10_screw.stl"), ("prusa-slicer", "PrusaSlicer/shapes/cylinder.stl"),
        ("assimp-testmodels", "assimp/models/PLY/Wuson.ply"), ("assimp-testmodels", "assimp/models/STL/Spider_binary.stl"),
        ("assimp-testmodels", "assimp/models/STL/3DSMaxExport.STL"), ("assimp-testmodels", "assimp/models/OBJ/regr01.obj")]


def _analyse(path: Path, tmp: Path, budget: int) -> dict:
    """In a fresh process, as ingest's analysis workers run it: a pytest process of the suite may have
    imported bpy (test_code_shape imports every module), and pymeshlab's decimation then stops at 2-3 x
    its target face count (seen in the suite, not in a process without bpy)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    task = partial(analyse_model, str(path), collision_dir=str(tmp / f"col{budget}"), face_budget=300, units="m",
                   up_axis="Y", proxy_max_vertices=32, facts_face_budget=budget)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(task).result()


def _same(a: dict, b: dict) -> list[str]:
    off = []
    for k in FACTS:
        x, y = a[k], b[k]
        if isinstance(x, float) and isinstance(y, float):
            if abs(x - y) > 1e-9 * max(abs(x), 1e-12):
                off.append(f"{k}: {x} != {y}")
        elif x != y:
            off.append(f"{k}: {x} != {y}")
    return off


@pytest.mark.parametrize("package,rel", REAL, ids=[Path(r).name for _, r in REAL])
def test_a_big_real_model_has_the_facts_of_the_whole_mesh(package: str, rel: str, tmp_path: Path) -> None:
    root, why = deb_tree(package)
    if root is None:
        pytest.skip(why)
    path = root / "usr" / "share" / rel
    whole = _analyse(path, tmp_path, 0)
    budget = 1000 if whole["face_count"] > 1000 else max(4, whole["face_count"] // 3)
    reduced = _analyse(path, tmp_path, budget)
    assert _same(whole, reduced) == []
    assert whole["facts_note"] is None
    note = reduced["facts_note"]
    copy_faces = int(note.split("from a ")[1].split("-face")[0].replace(",", ""))
    assert f"{whole['face_count']:,} faces" in note and 0 < copy_faces <= 1.25 * budget < whole["face_count"]
    assert Path(reduced["collision_path"]).is_file() and 0 < reduced["collision_face_count"] <= 300
    assert reduced["geometry_hash"] != whole["geometry_hash"]  # the hash is the copy's: said in the note


def test_the_copy_keeps_the_shape_a_watertight_sphere_and_an_open_sheet(tmp_path: Path) -> None:
    """Files the test writes: an icosphere (closed: volume), and a sheet (open: no volume), both above budget."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.04)  # 20,480 faces
    bowl = sphere.submesh([np.flatnonzero(sphere.triangles_center[:, 2] < 0.01)], append=True)  # open
    for name, mesh in (("ball.ply", sphere), ("bowl.obj", bowl)):
        mesh.export(tmp_path / name)
        whole, reduced = _analyse(tmp_path / name, tmp_path, 0), _analyse(tmp_path / name, tmp_path, 2000)
        assert _same(whole, reduced) == [] and reduced["facts_note"], name
        assert (reduced["volume"] is not None) == (name == "ball.ply") == reduced["watertight"]
        collision = trimesh.load(reduced["collision_path"], force="mesh")
        size = max(whole["dim_x"], whole["dim_y"], whole["dim_z"])
        assert abs(float(collision.extents.max()) - size) < 0.05 * size, name  # the copy has the object's size


def _absurd_files(root: Path) -> dict[str, Path]:
    """A real model (glmark2's bunny) written with its coordinates x1e30, with one vertex far, with inf, with nan."""
    base = trimesh.load(root / "usr/share/glmark2/models/bunny.obj", force="mesh", process=False)
    v, f = np.asarray(base.vertices, dtype=np.float64), np.asarray(base.faces)
    files = {}
    for name, verts in {"scaled_1e30": v * 1e30, "one_vertex_far": np.vstack([v[:-1], [[1e30, 0.0, 0.0]]]),
                        "inf": np.where(np.arange(len(v))[:, None] == 5, np.inf, v),
                        "nan": np.where(np.arange(len(v))[:, None] == 5, np.nan, v)}.items():
        path = root.parent / f"{name}.obj"
        path.write_text("".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in verts)
                        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
        files[name] = path
    return files


def test_absurd_coordinates_are_broken_with_the_reason_and_nothing_on_stderr(tmp_path: Path, capfd, catalog) -> None:
    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject
    from mixcount.config import load_config
    from mixcount.curation.finding.quality_flags import _broken_kind

    root, why = deb_tree("glmark2-data")
    if root is None:
        pytest.skip(why)
    work = tmp_path / "pkg"
    work.mkdir()
    (work / "usr").symlink_to(root / "usr")
    files = _absurd_files(work)
    for name, path in files.items():
        with pytest.raises(IngestError) as info:
            _analyse(path, tmp_path, 1000)
        reason = info.value.reason
        assert ("absurd coordinates" in reason and f"{ABSURD_M:.0e}" in reason) if "1e30" in name or "far" in name \
            else "inf or nan" in reason, (name, reason)
        assert _broken_kind(reason) == "degenerate model"
    lib = tmp_path / "lib"
    for name, path in files.items():
        (lib / name).mkdir(parents=True)
        (lib / name / "model.obj").write_bytes(path.read_bytes())
    capfd.readouterr()
    summary = ingest_paths(catalog, [lib], config=load_config([], ["ingest.workers=1"]))
    err = capfd.readouterr().err
    assert summary.broken == 4 and "Warning" not in err and "invalid value" not in err, err
    with catalog.session() as s:
        objs = {o.name: o for o in s.scalars(select(CatalogObject))}
    assert all(o.status == "broken" for o in objs.values())
    assert "1e+30 m" in objs["one_vertex_far"].error and "1 of" in objs["one_vertex_far"].error
    assert json.loads(objs["inf"].metadata_json or "{}")["ingest"]["layout"]


def _collision_hull(path: str, out: str, budget: int, factor: int) -> tuple[float, list[float], int]:
    """In a fresh process: the collision mesh of ``path`` built from a copy of ``factor`` x ``budget`` faces."""
    import mixcount.catalog.mesh as M

    M.COLLISION_INPUT_FACTOR = factor
    faces = M.build_collision_mesh(M.load_normalised(Path(path)).mesh, Path(out), budget)
    col = trimesh.load(out, force="mesh")
    return float(col.convex_hull.volume), [float(x) for x in col.extents], faces


def test_a_collision_mesh_from_a_clustered_copy_keeps_the_shape(tmp_path: Path) -> None:
    """A mesh over COLLISION_INPUT_FACTOR x the budget is clustered before the quadric collapse (issue 69): the
    collision mesh is as close to the shape's hull volume and box as the collapse of the whole mesh (1 %)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from mixcount.catalog.mesh import COLLISION_INPUT_FACTOR

    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.04)  # 81,920 faces
    sphere.vertices *= [1.0, 0.7, 1.3]
    sphere.export(tmp_path / "egg.ply")
    budget = 300
    assert len(sphere.faces) > COLLISION_INPUT_FACTOR * budget
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        direct = pool.submit(_collision_hull, str(tmp_path / "egg.ply"), str(tmp_path / "a.ply"), budget, 10**9).result()
        copied = pool.submit(_collision_hull, str(tmp_path / "egg.ply"), str(tmp_path / "b.ply"), budget,
                             COLLISION_INPUT_FACTOR).result()
    assert 0 < copied[2] <= budget and 0 < direct[2] <= budget
    true_volume, true_extents = float(sphere.convex_hull.volume), np.sort(sphere.extents)
    off = [(abs(hull - true_volume) / true_volume, float(np.abs(np.sort(ext) / true_extents - 1.0).max()))
           for hull, ext, _ in (direct, copied)]
    # seen: direct 12.7 % under the egg's hull volume, the clustered copy 4.4 %; boxes within 1-2 %
    assert off[1][0] <= off[0][0] + 0.01 and off[1][1] <= max(off[0][1], 0.03), off
