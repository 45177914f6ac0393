"""Real folders as they come (issue 52): a user's folders of package models ingest with nothing broken.

The library (:mod:`tests.package_folders`) is shaped like pybullet's ``pybullet_data`` copied into
person-named folders: missing ``.mtl``, a missing texture, ``../`` and Windows texture paths, URDF/SDF
beside Z-up meshes, collision companions and a level of detail, ``red_mug/`` and ``blue_mug/`` both
holding ``mug.obj``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from sqlalchemy import select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject, Flag, SourceFolder
from mixcount.config import load_config
from tests.package_folders import COMPANION_FILES, EXPECTED, build_package_folders

PROJECT_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _objects(catalog):
    with catalog.session() as s:
        objs = s.scalars(select(CatalogObject).order_by(CatalogObject.id)).all()
        flags = {o.id: sorted(f.kind for f in s.scalars(select(Flag).where(Flag.object_id == o.id))) for o in objs}
    return {o.name: o for o in objs}, flags


@pytest.fixture(scope="module")
def package_library(tmp_path_factory):
    return build_package_folders(tmp_path_factory.mktemp("packages") / "My models")


def test_package_folders_ingest_named_upright_and_whole(package_library, catalog):
    config = load_config([], ["ingest.workers=1"])
    summary = ingest_paths(catalog, [package_library], config=config)
    assert summary.broken == 0, summary.broken_objects
    assert summary.new == len(EXPECTED)
    objs, flags = _objects(catalog)
    # every object named by its folder; companions are no objects
    assert set(objs) == set(EXPECTED)
    assert not any(o.model_path.endswith(COMPANION_FILES) for o in objs.values())
    for name, want in EXPECTED.items():
        obj = objs[name]
        info = json.loads(obj.metadata_json)["ingest"]
        assert obj.status == "active" and obj.category == want.category, (name, obj.category)
        # upright: the height of the object is its Z extent, whatever axis its file had up
        assert obj.dims == pytest.approx(want.dims, rel=0.03), (name, obj.dims)
        assert obj.source_up_axis == want.up_axis, (name, info["up_axis_reason"])
        assert info["up_axis_reason"], name
        assert flags[obj.id] == sorted(want.warnings), (name, flags[obj.id])
        assert bool(info["collision_source"]) == want.collision_companion, (name, info["collision_source"])
    assert "URDF" in json.loads(objs["red_mug"].metadata_json)["ingest"]["up_axis_reason"]
    assert "STL" in json.loads(objs["Gripper finger"].metadata_json)["ingest"]["up_axis_reason"]
    assert objs["Sugar cube"].source_units == "0.02"  # the URDF's scale
    # textures found by name (../cube.png, a Windows path) are used: the model is staged with its .mtl
    # rewritten to name them, so the loaders see the image; a missing one leaves a default material
    assert objs["Dice"].textured and objs["red_mug"].textured and objs["Rubber duck"].textured
    assert not objs["Jenga block"].textured and not objs["Sugar cube"].textured
    assert "cube.mtl" in " ".join(w for n, w in summary.warnings if n == "Sugar cube")

    # catalog show --json / list --json carry the reason, the warnings and the collision companion
    from mixcount.catalog.records import object_record

    with catalog.session() as s:
        record = object_record(s, s.get(CatalogObject, objs["red_mug"].id), caption_warnings=None)
    assert "URDF mug.urdf" in record["up_axis_reason"] and record["collision_source"].endswith("mug_col.obj")
    assert any("found by name" in w for w in record["ingest_warnings"])

    # a second ingest changes nothing
    again = ingest_paths(catalog, [package_library], config=config)
    assert (again.new, again.updated, again.broken, again.unchanged) == (0, 0, 0, len(EXPECTED))
    assert not again.reoriented and not again.invalidated


def test_up_axis_stated_once_is_kept_and_a_change_is_reported(tmp_path, catalog):
    lib = build_package_folders(tmp_path / "lib")
    config = load_config([], ["ingest.workers=1"])
    first = ingest_paths(catalog, [lib / "Kitchen chair", lib / "Teddy bear"], config=config, up_axis="Y")
    assert first.new == 2
    objs, _ = _objects(catalog)
    assert objs["Kitchen chair"].source_up_axis == "Y"
    with catalog.session() as s:
        assert sorted(r.up_axis for r in s.scalars(select(SourceFolder))) == ["Y", "Y"]
    # without the option: kept, nothing changes
    again = ingest_paths(catalog, [lib / "Kitchen chair", lib / "Teddy bear"], config=config)
    assert (again.unchanged, again.updated) == (2, 0) and not again.reoriented
    objs, _ = _objects(catalog)
    reason = json.loads(objs["Kitchen chair"].metadata_json)["ingest"]["up_axis_reason"]
    assert "--up-axis" in reason
    # auto forgets it: the URDF decides again, and the run says which objects turned
    turned = ingest_paths(catalog, [lib / "Kitchen chair", lib / "Teddy bear"], config=config, up_axis="auto")
    assert [(n, a, b) for n, a, b, _ in turned.reoriented] == [("Kitchen chair", "Y", "Z")]
    assert turned.updated == 1 and turned.unchanged == 1  # the teddy's URDF says Y too
    with catalog.session() as s:
        assert s.scalars(select(SourceFolder)).all() == []


@pytest.mark.slow
def test_cli_reports_warnings_and_reorientation(tmp_path):
    lib = build_package_folders(tmp_path / "lib")
    db = str(tmp_path / "c.db")
    env = {**os.environ, "COLUMNS": "400"}

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "mixcount", "--db", db, "catalog", "ingest", *args],
                              cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=300, env=env)

    res = cli(str(lib / "Sugar cube"), str(lib / "Kitchen chair"), "--up-axis", "Y")
    assert res.returncode == 0, res.stderr
    assert "warning: Sugar cube: missing material file: cube.mtl" in res.stderr
    assert "ingest: 2/2 (100 %)" in res.stderr  # progress as plain lines: stderr is not a terminal here
    res = cli(str(lib / "Sugar cube"), str(lib / "Kitchen chair"), "--up-axis", "auto", "--json")
    assert res.returncode == 0, res.stderr
    assert "re-oriented Kitchen chair: up axis Y -> Z" in res.stderr
    summary = json.loads(res.stdout)
    assert {r["name"] for r in summary["reoriented"]} == {"Kitchen chair", "Sugar cube"}


def test_a_container_read_lying_is_stood_up_by_its_opening(tmp_path, catalog):
    """An OBJ bowl modelled Z-up with nothing beside it is read Y-up (ingest.assume_up_axis) and so lies on
    its side; its opening faces +Z of the file, so ingest measures it again Z-up, says why, and a rerun
    keeps it (unchanged). A closed box is left as the rule reads it."""
    import trimesh

    cyl = trimesh.creation.cylinder(radius=0.08, height=0.06, sections=48)
    bowl = trimesh.Trimesh(cyl.vertices, cyl.faces[cyl.face_normals[:, 2] < 0.9])  # open towards +Z
    (tmp_path / "lib" / "Salad bowl").mkdir(parents=True)
    bowl.export(tmp_path / "lib" / "Salad bowl" / "bowl.obj")
    (tmp_path / "lib" / "Shoe box").mkdir()
    trimesh.creation.box(extents=(0.3, 0.2, 0.1)).export(tmp_path / "lib" / "Shoe box" / "box.obj")
    config = load_config([], ["ingest.workers=1", "ingest.assume_up_axis=Y"])
    summary = ingest_paths(catalog, [tmp_path / "lib"], config=config)
    assert (summary.new, summary.broken) == (2, 0)
    objs, _ = _objects(catalog)
    stood = objs["Salad bowl"]
    assert stood.container and stood.source_up_axis == "Z"
    assert stood.dims == pytest.approx((0.16, 0.16, 0.06), abs=1e-3)
    assert json.loads(stood.metadata_json)["ingest"]["up_axis_reason"].startswith("its opening faces +Z")
    assert summary.container_warnings == [] and not summary.invalidated
    assert objs["Shoe box"].source_up_axis == "Y"
    again = ingest_paths(catalog, [tmp_path / "lib"], config=config)
    assert (again.unchanged, again.updated, again.reoriented) == (2, 0, [])
