"""A user's own objects as they export them (issue 56): units decided and said, one folder one object,
STEP, MuJoCo XML.

Files the tests write (an STL in millimetres, an STL in metres, parts of one object, separate models at
the origin, a GLB with a numeric ``units`` entry, an MJCF placing millimetre parts) and real files copied
out of public packages (:mod:`tests.cad_folders`: prusa-slicer, assimp-testmodels, metaworld,
bd_warehouse), which skip with the reason when they cannot be had.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from sqlalchemy import select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject
from mixcount.catalog.records import object_record
from mixcount.config import load_config
from tests.cad_folders import EXPECTED, build_cad_folders

PROJECT_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

TOY_CAR_MJCF = """<mujoco model="toy car">
  <compiler meshdir="meshes"/>
  <asset>
    <mesh name="body" file="meshes/body.stl" scale="0.001 0.001 0.001"/>
    <mesh name="wheel" file="meshes/wheel.stl" scale="0.001 0.001 0.001"/>
    <mesh name="hull" file="meshes/hull.stl" scale="0.001 0.001 0.001"/>
  </asset>
  <default>
    <default class="visual"><geom contype="0" conaffinity="0" group="2"/></default>
    <default class="collision"><geom group="3"/></default>
  </default>
  <worldbody>
    <body name="toy_car" pos="0 0 0.1">
      <geom class="visual" mesh="body"/>
      <geom class="visual" mesh="wheel" pos="0.04 0.025 -0.015" euler="90 0 0"/>
      <geom class="visual" mesh="wheel" pos="-0.04 0.025 -0.015" euler="90 0 0"/>
      <geom class="collision" mesh="hull"/>
    </body>
  </worldbody>
</mujoco>
"""


def _cfg():
    return load_config([], ["ingest.workers=1"])


def _records(catalog) -> dict[str, dict]:
    with catalog.session() as s:
        return {o.name: object_record(s, o, caption_warnings=None) for o in s.scalars(select(CatalogObject))}


def _write_library(root):
    """The folders a user makes of their own exports."""
    nut = root / "Hex nut"  # an STL in millimetres, as CAD writes it: 10 mm across
    nut.mkdir(parents=True)
    trimesh.creation.cylinder(radius=5.0, height=4.0, sections=6).export(nut / "nut.stl")
    finger = root / "Gripper finger"  # an STL in metres: 6 cm read as mm is no object's size
    finger.mkdir()
    trimesh.creation.box(extents=(0.01, 0.02, 0.06)).export(finger / "finger.stl")
    hammer = root / "Hammer"  # parts in one frame: the head sits on the handle's end
    hammer.mkdir()
    handle = trimesh.creation.cylinder(radius=12.0, height=280.0)
    handle.apply_translation((0, 0, 140.0))
    handle.export(hammer / "hammer_handle.stl")
    head = trimesh.creation.box(extents=(100.0, 30.0, 30.0))
    head.apply_translation((0, 0, 280.0))
    head.export(hammer / "hammer_head.stl")
    shapes = root / "Print shapes"  # separate models, each at the origin (a slicer's shapes)
    shapes.mkdir()
    trimesh.creation.box(extents=(25.0, 25.0, 25.0)).export(shapes / "box.stl")
    trimesh.creation.icosphere(radius=15.0).export(shapes / "sphere.stl")
    trimesh.creation.cone(radius=14.0, height=25.0).export(shapes / "cone.stl")
    mug = root / "Mug in centimetres"  # a GLB in cm, with a units entry as a JSON number
    mug.mkdir()
    trimesh.creation.cylinder(radius=4.0, height=10.0).export(mug / "mug.glb")
    (mug / "metadata.json").write_text(json.dumps({"name": "Mug in centimetres", "units": 0.01}))
    split = root / "Split hammer"  # parts that the user wants as separate objects
    split.mkdir()
    for name in ("hammer_handle.stl", "hammer_head.stl"):
        (split / name).write_bytes((hammer / name).read_bytes())
    (split / "metadata.json").write_text(json.dumps({"parts": "separate"}))
    car = root / "Toy car"  # an MJCF placing millimetre parts, with a collision-only hull
    (car / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(100.0, 40.0, 30.0)).export(car / "meshes" / "body.stl")
    trimesh.creation.cylinder(radius=10.0, height=5.0).export(car / "meshes" / "wheel.stl")
    trimesh.creation.box(extents=(100.0, 48.0, 40.0)).export(car / "meshes" / "hull.stl")
    (car / "toy_car.xml").write_text(TOY_CAR_MJCF)
    return root


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    from mixcount.catalog.db import open_catalog

    root = _write_library(tmp_path_factory.mktemp("cad") / "My exports")
    cat = open_catalog(f"sqlite:///{tmp_path_factory.mktemp('cadcat') / 'catalog.db'}", data_dir="")
    summary = ingest_paths(cat, [root], config=_cfg())
    yield summary, _records(cat), root
    cat.close()


def test_units_decided_in_order_and_recorded_with_their_reason(written):
    summary, recs, _root = written
    assert summary.broken == 0, summary.broken_objects
    nut = recs["Hex nut"]  # STL: millimetres by the format's convention
    assert nut["source_units"] == "mm" and nut["units_reason"].startswith("format: STL")
    assert max(nut["dims_m"]) == pytest.approx(0.010, rel=0.02)
    finger = recs["Gripper finger"]  # implausible in mm: re-read by the size prior, and said
    assert finger["source_units"] == "m" and finger["units_reason"].startswith("size prior")
    assert finger["dims_m"] == pytest.approx([0.01, 0.02, 0.06], rel=0.02)
    mug = recs["Mug in centimetres"]  # a number in metadata.json beside a GLB
    assert mug["source_units"] == "0.01" and mug["units_reason"].startswith("stated")
    assert max(mug["dims_m"]) == pytest.approx(0.10, rel=0.02)
    assert {"name": "Hex nut", "units": "mm"}.items() <= next(
        r for r in summary.as_dict()["rescaled"] if r["name"] == "Hex nut").items()
    assert summary.as_dict()["rescaled_by"]["format"] >= 3  # the nut, the shapes...


def test_one_folder_one_object_and_separate_models_stay_separate(written):
    _summary, recs, _root = written
    hammer = recs["Hammer"]
    assert hammer["parts"] == ["hammer_handle.stl", "hammer_head.stl"] and "parts of one object" in hammer["parts_rule"]
    assert hammer["dims_m"] == pytest.approx([0.1, 0.03, 0.295], abs=0.002)  # the head on top of the handle
    assert not any(n.startswith("hammer_") for n in recs if n not in ("hammer_handle", "hammer_head"))
    assert {"box", "sphere", "cone"} <= set(recs)  # same origin, unrelated names: three models
    assert "separate models" in recs["box"]["parts_rule"]
    assert {"hammer_handle", "hammer_head"} <= set(recs)  # "parts": "separate" in metadata.json
    assert recs["hammer_head"]["parts_rule"].endswith("stated (parts: separate)")


def test_mjcf_places_parts_and_names_collision_meshes(written):
    _summary, recs, _root = written
    car = recs["Toy car"]
    assert car["parts"] == ["body.stl", "wheel.stl", "wheel.stl"] and "MJCF toy_car.xml" in car["parts_rule"]
    assert car["source_units"] == "0.001" and car["units_reason"].startswith("description: MJCF")
    assert car["source_up_axis"] == "Z" and "MJCF" in car["up_axis_reason"]
    assert car["dims_m"] == pytest.approx([0.1, 0.0475, 0.04], abs=0.002)  # wheels turned and placed
    assert car["collision_source"] and car["collision_source"].endswith("hull.stl")
    assert "hull" not in recs and "body" not in recs and "wheel" not in recs


def test_cli_units_and_parts_flags(tmp_path):
    lib = tmp_path / "lib"
    shapes = lib / "Print shapes"
    shapes.mkdir(parents=True)
    trimesh.creation.box(extents=(25.0, 25.0, 25.0)).export(shapes / "box.stl")
    trimesh.creation.icosphere(radius=15.0).export(shapes / "sphere.stl")
    env = {**os.environ, "PYTHONPATH": PROJECT_ROOT}
    db = ["--db", str(tmp_path / "c.db")]
    bad = subprocess.run([sys.executable, "-m", "mixcount", *db, "catalog", "ingest", str(lib), "--parts", "glue"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert bad.returncode == 2 and "unknown parts rule" in bad.stderr and "Traceback" not in bad.stderr
    run = subprocess.run([sys.executable, "-m", "mixcount", *db, "catalog", "ingest", str(lib), "--parts", "merge",
                          "--units", "cm", "--json"], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["new"] == 1 and summary["rescaled_by"] == {"stated": 1}
    listed = subprocess.run([sys.executable, "-m", "mixcount", *db, "catalog", "list", "--json"],
                            capture_output=True, text=True, env=env, timeout=120)
    (obj,) = json.loads(listed.stdout)
    assert obj["name"] == "Print shapes" and obj["source_units"] == "cm"
    assert obj["units_reason"] == "stated: catalog ingest --units cm" and obj["parts_rule"].endswith("(parts: merge)")
    assert max(obj["dims_m"]) == pytest.approx(0.30, rel=0.02)


@pytest.fixture(scope="module")
def real_library(tmp_path_factory):
    root, missing = build_cad_folders(tmp_path_factory.mktemp("real") / "My parts")
    if not any(root.iterdir()):
        pytest.skip("; ".join(missing))
    from mixcount.catalog.db import open_catalog

    cat = open_catalog(f"sqlite:///{tmp_path_factory.mktemp('realcat') / 'catalog.db'}", data_dir="")
    summary = ingest_paths(cat, [root], config=load_config([], ["ingest.workers=2"]))
    yield summary, _records(cat), missing
    cat.close()


def test_real_exports_are_objects_of_their_real_size(real_library):
    summary, recs, missing = real_library
    assert summary.broken == 0, summary.broken_objects
    got = {name: exp for name, exp in EXPECTED.items() if name in recs}
    assert set(recs) == set(got)  # one object per folder, named by it
    assert len(got) >= 12 or missing, missing
    for name, want in got.items():
        rec = recs[name]
        assert rec["source_units"] == want.units and rec["units_reason"].startswith(want.basis), (name, rec)
        assert len(rec["parts"]) == (want.parts if want.parts > 1 else 0), (name, rec["parts"])
        if want.largest_m is not None:
            ratio = max(rec["dims_m"]) / want.largest_m
            assert 0.5 <= ratio <= 2.0, (name, rec["dims_m"], want.largest_m)
    if "Wuson" in recs:  # a PLY with no unit, implausible in ingest.assume_units: said, not re-read
        assert "would be" in recs["Wuson"]["units_reason"]
        # and assimp's textured box, a glTF cube of 1 m centred on the origin, is normalised: no trustworthy size
        # (issue 70, mixcount.sizes.decide_size), said
        assert sorted(n for n, _r in summary.implausible) == sorted(["Wuson"] + ["Textured box"] * ("Textured box" in recs))


def test_step_and_stl_of_one_model_are_one_object(real_library):
    _summary, recs, missing = real_library
    rec = recs.get("Hex nut M8 (STEP and STL)")
    if rec is None:
        pytest.skip("; ".join(missing))
    assert rec["metadata"]["other_formats"] == ["hexnut_m8.stl"]
    assert rec["metadata"]["source_model_path"].endswith("hexnut_m8.step") and rec["model_path"].endswith(".glb")
    stl = trimesh.load(rec["metadata"]["source_model_path"].replace(".step", ".stl"))
    assert max(rec["dims_m"]) == pytest.approx(float(np.max(stl.extents)) * 0.001, rel=0.01)  # STEP = STL in mm
