"""A MuJoCo body file copied without the file that declares its meshes (issue 70 item 6): metaworld's
``mug.xml`` names meshes ``mug`` and ``handle`` that its ``coffeemachine_dependencies.xml`` declares; a user
copies the body file and the two STL files into one folder. The meshes are found by name beside it, the
object is one mug of two parts, Z-up as MuJoCo's world is, and warnings say which files were used. Before,
the description was ignored: two objects, the handle a separate "object"."""

from __future__ import annotations

import json
import shutil

import pytest
from public_packages import METAWORLD, wheel_tree

from mixcount.cli import main


def test_undeclared_meshes_are_found_by_name_and_said(tmp_path, capsys):
    root, why = wheel_tree(METAWORLD)
    if root is None:
        pytest.skip(why)
    objects = root / "metaworld/assets/objects"
    mug = tmp_path / "lib" / "Mug"
    mug.mkdir(parents=True)
    for src in (objects / "assets/mug.xml", objects / "meshes/coffeemachine/mug.stl",
                objects / "meshes/coffeemachine/handle.stl"):
        shutil.copy(src, mug / src.name)
    db = ["--db", str(tmp_path / "catalog.db"), "--config", "quick"]
    assert main([*db, "catalog", "ingest", str(tmp_path / "lib"), "--workers", "1"]) == 0
    printed = capsys.readouterr()
    said = printed.out + printed.err
    assert "mug.stl in its folder is used" in said and "handle.stl in its folder is used" in said
    assert main([*db, "catalog", "list", "--json"]) == 0
    objs = json.loads(capsys.readouterr().out)
    assert len(objs) == 1, [o["name"] for o in objs]
    obj = objs[0]
    assert obj["parts"] == ["mug.stl", "handle.stl"] and obj["source_up_axis"] == "Z"
    assert obj["up_axis_reason"].startswith("MJCF mug.xml")
    assert any("no <asset> beside it declares" in w for w in obj["ingest_warnings"])
    dx, dy, dz = obj["dims_m"]
    assert 0.04 < dz < 0.09 and max(dx, dy) < 0.1  # a mug standing up, about 6.6 cm tall
