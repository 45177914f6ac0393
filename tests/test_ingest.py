"""Ingest on real files and a real SQLite catalog: DTC layout, plain folders of every format, units and
up-axis handling, idempotent reruns, changed files keeping their id, and a killed ingest resumed."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import func, select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, IngestRun, ReviewDecision, Split
from mixcount.config import load_config
from mixcount.demo.library import generate_demo_library

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def cfg(**ingest):
    return load_config([], [f"ingest.{k}={json.dumps(v)}" for k, v in ingest.items()])


def objects_by_name(catalog) -> dict[str, CatalogObject]:
    with catalog.session() as s:
        return {o.name: o for o in s.scalars(select(CatalogObject)).all()}


def textured_box(extents, colour=(200, 30, 30)) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=extents)
    uv = np.c_[mesh.vertices[:, 0] > 0, mesh.vertices[:, 1] > 0].astype(float)
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (8, 8), colour))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return mesh


def write_usd(path: Path, *, extents_cm=(4.0, 6.0, 10.0), up="Y", mpu=0.01) -> None:
    """A box prim under a translated Xform, stage in centimetres (default) and Y-up, written with pxr."""
    from pxr import Gf, Usd, UsdGeom

    box = trimesh.creation.box(extents=extents_cm)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, up)
    xf = UsdGeom.Xform.Define(stage, "/World")
    xf.AddTranslateOp().Set(Gf.Vec3d(5, 50, 0))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Box")
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in box.vertices])
    mesh.CreateFaceVertexCountsAttr([3] * len(box.faces))
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in box.faces.flatten()])
    stage.GetRootLayer().Save()


def test_dtc_layout_facts_match_ground_truth(tmp_path, catalog):
    lib = tmp_path / "lib"
    truth = generate_demo_library(lib, seed=1, n_objects=12)
    summary = ingest_paths(catalog, [lib], config=cfg(workers=2))
    assert summary.total == truth["expected"]["total"]
    assert summary.new == truth["expected"]["active"]
    assert summary.broken == truth["expected"]["broken"] == 2
    with catalog.session() as s:  # by folder: a DTC folder's name, a plain folder's model's folder
        objs = {o.source_id if o.source == "dtc" else Path(o.model_path).parent.name: o
                for o in s.scalars(select(CatalogObject))}
    assert set(objs) == {o["folder"] for o in truth["objects"]}
    for entry in truth["objects"]:
        obj = objs[entry["folder"]]
        assert obj.source == entry["source"] and obj.category == entry["category"]
        if entry["source"] == "folder":  # another source: OBJ in cm (or undeclared: m) read Y-up, named by its metadata.json
            assert obj.status == "active" and obj.name == entry["name"] and obj.source_units == entry["units"]
            assert obj.dims == pytest.approx(tuple(entry["dims_m"]), abs=2e-5) and obj.textured
            continue
        assert obj.source_id == entry["folder"]
        if entry["kind"] == "broken":
            assert obj.status == "broken" and obj.error
            continue
        assert obj.status == "active", obj.error
        # metres and Z-up: the GLB is Y-up with node transforms, the truth is the Z-up geometry
        assert obj.dims == pytest.approx(tuple(entry["dims_m"]), abs=2e-5)
        assert obj.source_units == "m" and obj.source_up_axis == "Y"
        assert obj.textured is True
        assert obj.license and "CC-BY" in obj.license
        assert json.loads(obj.metadata_json)["metadata"]["category"] == entry["category"]
        assert Path(obj.model_path).is_absolute() and obj.model_path.endswith("3d-asset.glb")
        assert Path(obj.collision_path).is_file() and obj.collision_path.endswith(".ply")
        assert 0 < obj.collision_face_count <= 2000
        assert obj.vertex_count > 0 and obj.face_count > 0 and obj.area > 0
    # exact copies share the content hash, recolours the geometry hash, rescales neither
    for a, b in truth["exact_copies"]:
        assert objs[a].content_hash == objs[b].content_hash
    for a, b in truth["recolours"]:
        assert objs[a].geometry_hash == objs[b].geometry_hash and objs[a].content_hash != objs[b].content_hash
    for a, b, factor in truth["rescales"]:
        assert objs[a].geometry_hash != objs[b].geometry_hash
        assert max(objs[b].dims) == pytest.approx(factor * max(objs[a].dims), rel=1e-4)
    balls = [o for o in objs.values() if o.category == "ball" and o.status == "active"]
    assert balls and all(o.watertight and o.volume and o.volume > 0 for o in balls)
    with catalog.session() as s:
        run = s.get(IngestRun, summary.run_id)
        assert run.status == "done" and run.n_new == summary.new and run.n_broken == 2


def test_dtc_category_from_folder_name_and_collision_budget(tmp_path, catalog):
    folder = tmp_path / "Markers_B07Z5P84J2_Peach"
    folder.mkdir()
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)  # 5120 faces
    sphere.export(folder / "3d-asset.glb")
    (folder / "metadata.json").write_text(json.dumps({"name": "Peach marker"}))
    (folder / "LICENSE.txt").write_text("CC0")
    (folder / "preview.jpg").write_bytes(b"not checked")
    summary = ingest_paths(catalog, [folder], config=cfg(collision_face_budget=300, workers=1))
    assert summary.new == 1
    obj = objects_by_name(catalog)["Markers_B07Z5P84J2_Peach"]
    assert obj.category == "marker"  # first token of the name, singular, lower case
    assert obj.license == "CC0"
    assert obj.face_count == 5120 and obj.collision_face_count <= 300
    assert obj.textured is False and obj.watertight is True
    assert obj.volume == pytest.approx(4 / 3 * np.pi * 0.05**3, rel=0.02)
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(obj.collision_path)
    assert ms.current_mesh().face_number() == obj.collision_face_count


def test_plain_folder_every_format(tmp_path, catalog):
    lib = tmp_path / "plain"
    (lib / "sub").mkdir(parents=True)
    # GLB whose node transform scales and rotates the geometry: dims must include the transform
    scene = trimesh.Scene()
    rot = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1])
    scale = np.diag([2.0, 2.0, 2.0, 1.0])
    scene.add_geometry(textured_box((0.01, 0.02, 0.03)), node_name="n", transform=rot @ scale)
    scene.export(lib / "mug_scaled.glb")
    # glTF with external buffers and an external texture
    files = textured_box((0.05, 0.06, 0.07), (20, 200, 20)).export(file_type="gltf")
    (lib / "sub" / "gltf").mkdir()
    for name, data in files.items():
        (lib / "sub" / "gltf" / name).write_bytes(data)
    # OBJ with a material and a texture, in centimetres (assume_units)
    obj_box = textured_box((3.0, 4.0, 5.0))
    obj_box.export(lib / "block_cm.obj")
    trimesh.creation.box(extents=(1.0, 2.0, 3.0)).export(lib / "eraser.ply")
    trimesh.creation.cylinder(radius=30.0, height=120.0).export(lib / "can.stl")  # STL: millimetres (issue 56)
    write_usd(lib / "sub" / "bottle.usda")
    from pxr import UsdUtils

    write_usd(tmp_path / "figurine.usdc", extents_cm=(1.0, 1.0, 1.0), up="Z", mpu=0.01)
    UsdUtils.CreateNewUsdzPackage(str(tmp_path / "figurine.usdc"), str(lib / "figurine.usdz"))
    (lib / "notes.txt").write_text("ignored: not a model")

    summary = ingest_paths(catalog, [lib], config=cfg(assume_units="cm", assume_up_axis="Y", workers=2))
    assert (summary.new, summary.broken) == (7, 0), summary.broken_objects
    objs = objects_by_name(catalog)
    # the glTF is the only model of its folder and its file name is generic: the folder names it
    assert set(objs) == {"mug_scaled", "gltf", "block_cm", "eraser", "can", "bottle", "figurine"}
    assert all(o.source == "folder" and o.status == "active" for o in objs.values())
    # GLB: 2x scale and 90 degrees about glTF's Y... here about Z of the glTF frame, then Y-up -> Z-up
    assert objs["mug_scaled"].dims == pytest.approx((0.04, 0.06, 0.02), abs=1e-6)
    assert objs["mug_scaled"].category == "mug" and objs["mug_scaled"].textured
    assert objs["gltf"].dims == pytest.approx((0.05, 0.07, 0.06), abs=1e-6)
    assert objs["gltf"].category == "gltf"  # generic stem "model": the folder name is the category
    assert objs["gltf"].textured
    assert objs["block_cm"].dims == pytest.approx((0.03, 0.05, 0.04), abs=1e-6)
    assert objs["block_cm"].source_units == "cm" and objs["block_cm"].textured
    assert objs["eraser"].dims == pytest.approx((0.01, 0.03, 0.02), abs=1e-6)
    # an STL is Z-up whatever ingest.assume_up_axis says (CAD tools write Z-up), and says why
    assert objs["can"].dims == pytest.approx((0.06, 0.06, 0.12), abs=1e-3)  # not ingest.assume_units
    assert objs["can"].source_up_axis == "Z" and objs["can"].source_units == "mm"
    assert "STL" in json.loads(objs["can"].metadata_json)["ingest"]["up_axis_reason"]
    assert objs["bottle"].source_units == "cm" and objs["bottle"].source_up_axis == "Y"
    assert objs["bottle"].dims == pytest.approx((0.04, 0.10, 0.06), abs=1e-6)
    assert objs["figurine"].source_up_axis == "Z"
    assert objs["figurine"].dims == pytest.approx((0.01, 0.01, 0.01), abs=1e-6)


def test_rerun_is_idempotent_and_keeps_ids(tmp_path, catalog):
    lib = tmp_path / "lib"
    generate_demo_library(lib, seed=2, n_objects=6)
    first = ingest_paths(catalog, [lib], config=cfg(workers=2))
    with catalog.session() as s:
        before = {o.source_id: (o.id, o.content_hash, o.updated_at, o.status) for o in s.scalars(select(CatalogObject))}
    second = ingest_paths(catalog, [lib], config=cfg(workers=2))
    assert second.new == 0 and second.updated == 0
    assert second.unchanged == first.new and second.broken == first.broken
    with catalog.session() as s:
        after = {o.source_id: (o.id, o.content_hash, o.updated_at, o.status) for o in s.scalars(select(CatalogObject))}
        runs = s.scalars(select(IngestRun).order_by(IngestRun.id)).all()
    assert after == before
    assert [r.status for r in runs] == ["done", "done"] and runs[1].n_unchanged == second.unchanged


def test_changed_file_updates_same_row_and_keeps_history(tmp_path, catalog):
    lib = tmp_path / "lib"
    folder = lib / "Mug_B0TESTMUG1_Red"
    folder.mkdir(parents=True)
    textured_box((0.08, 0.08, 0.1)).export(folder / "3d-asset.glb")
    (folder / "metadata.json").write_text(json.dumps({"category": "mug"}))
    ingest_paths(catalog, [lib], config=cfg(workers=1))
    with catalog.session() as s:
        obj = s.scalars(select(CatalogObject)).one()
        oid, old_hash, old_coll = obj.id, obj.content_hash, obj.collision_path
        s.add(Flag(object_id=oid, kind="size_outlier", score=0.7, reason="test"))
        s.add(CaptionSet(object_id=oid, captioner="stub", provider="stub", model="stub", prompt_version="v",
                         short="mug", concise="red mug", detailed="a red mug", response_hash="x", active=True))
        s.add(ReviewDecision(object_id=oid, decision="accept", reviewer="t"))
        s.add(Split(object_id=oid, split="val", method="random", seed=0))
        s.commit()

    # metadata-only change: updated without mesh work, facts kept
    (folder / "metadata.json").write_text(json.dumps({"category": "cup"}))
    summary = ingest_paths(catalog, [lib], config=cfg(workers=1))
    assert summary.updated == 1
    obj = objects_by_name(catalog)["Mug_B0TESTMUG1_Red"]
    assert obj.id == oid and obj.category == "cup" and obj.content_hash == old_hash

    # the model changes: new facts, same row, history intact
    textured_box((0.1, 0.1, 0.12), (10, 10, 200)).export(folder / "3d-asset.glb")
    summary = ingest_paths(catalog, [lib], config=cfg(workers=1))
    assert (summary.updated, summary.new) == (1, 0)
    with catalog.session() as s:
        assert s.scalar(select(func.count()).select_from(CatalogObject)) == 1
        obj = s.scalars(select(CatalogObject)).one()
        assert obj.id == oid and obj.content_hash != old_hash
        assert obj.dims == pytest.approx((0.1, 0.12, 0.1), abs=1e-6)
        assert obj.collision_path != old_coll and Path(obj.collision_path).is_file()
        # the category changed, then the model: flags and captions of the old object are gone (the next
        # filter / caption redo them, tests/test_ingest_stale.py); a person's decision and the split stay
        assert [f.kind for f in obj.flags] == [] and [c.short for c in obj.caption_sets] == []
        assert [r.decision for r in obj.reviews] == ["accept"]
        assert obj.split.split == "val"

    # it breaks, then gets fixed: broken keeps the row too, and the fix brings it back
    (folder / "3d-asset.glb").write_bytes(b"garbage")
    assert ingest_paths(catalog, [lib], config=cfg(workers=1)).broken == 1
    assert objects_by_name(catalog)["Mug_B0TESTMUG1_Red"].status == "broken"
    textured_box((0.1, 0.1, 0.12)).export(folder / "3d-asset.glb")
    assert ingest_paths(catalog, [lib], config=cfg(workers=1)).updated == 1
    obj = objects_by_name(catalog)["Mug_B0TESTMUG1_Red"]
    assert (obj.id, obj.status, obj.error) == (oid, "active", None)


def test_collision_budget_change_reanalyses(tmp_path, catalog):
    path = tmp_path / "ball.glb"
    trimesh.creation.icosphere(subdivisions=3, radius=0.03).export(path)
    ingest_paths(catalog, [path], config=cfg(workers=1))
    summary = ingest_paths(catalog, [path], config=cfg(collision_face_budget=100, workers=1))
    assert summary.updated == 1
    assert objects_by_name(catalog)["ball"].collision_face_count <= 100


@pytest.mark.slow
def test_killed_ingest_resumes_without_duplicates(tmp_path):
    lib = tmp_path / "lib"
    truth = generate_demo_library(lib, seed=4, n_objects=40)  # 40 + containers + traps + broken
    total = truth["expected"]["total"]
    db = tmp_path / "kill.db"
    exe = [sys.executable, "-m", "mixcount", "--db", str(db)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(exe + ["catalog", "ingest", str(lib), "--workers", "1"], cwd=PROJECT_ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    seen = 0
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if db.exists():
                try:
                    with sqlite3.connect(db, timeout=5) as con:
                        seen = con.execute("select count(*) from objects").fetchone()[0]
                except sqlite3.OperationalError:
                    seen = 0  # tables not migrated yet
                if seen >= 3:
                    break
            time.sleep(0.02)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the CLI and its workers, mid-run
        proc.wait()
    assert 3 <= seen < total, f"the kill should land mid-run (saw {seen} of {total})"
    with sqlite3.connect(db) as con:
        at_kill = con.execute("select count(*) from objects").fetchone()[0]
        assert con.execute("select status from ingest_runs").fetchall() == [("running",)]
    assert at_kill < total

    done = subprocess.run(exe + ["catalog", "ingest", str(lib), "--json"], cwd=PROJECT_ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["total"] == total and summary["new"] + summary["unchanged"] + summary["broken"] == total
    assert summary["unchanged"] >= at_kill - 2  # what was committed before the kill is not redone
    with sqlite3.connect(db) as con:
        rows = con.execute("select source_id, status from objects").fetchall()
    assert len(rows) == total == len({r[0] for r in rows})
    # a DTC object's key is its folder, a plain folder object's the model file's path
    assert {r[0] for r in rows} == {o["folder"] if o["source"] == "dtc" else str(lib.resolve() / o["model"])
                                    for o in truth["objects"]}
    assert sum(r[1] == "broken" for r in rows) == truth["expected"]["broken"]
