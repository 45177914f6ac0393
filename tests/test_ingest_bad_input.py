"""Every bad input: the object is `broken` with a specific reason and the batch goes on;
a missing PATH or an unwritable database is a one-line error with a non-zero exit."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.ingest import discover, ingest_paths
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.config import load_config
from mixcount.errors import CatalogError

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def good_glb(path: Path, size: float = 0.05) -> bytes:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = trimesh.creation.box(extents=(size, size, size)).export(file_type="glb")
    path.write_bytes(data)
    return data


def dtc(root: Path, name: str, payload: bytes | None = None) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    if payload is not None:
        (folder / "3d-asset.glb").write_bytes(payload)
    (folder / "metadata.json").write_text("{}")
    return folder


@pytest.fixture
def bad_library(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A library of good and bad objects; returns it and {source_id suffix: expected reason fragment}."""
    lib = tmp_path / "lib"
    lib.mkdir()
    good = good_glb(lib / "Ball_B0GOOD0001_Red" / "3d-asset.glb")
    (lib / "Ball_B0GOOD0001_Red" / "metadata.json").write_text("{}")
    good_glb(lib / "plain" / "cube.glb")
    expect: dict[str, str] = {}

    dtc(lib, "Ball_B0TRUNC001_Cut", good[: len(good) // 2])
    expect["Ball_B0TRUNC001_Cut"] = "truncated GLB: header declares"

    bad_json = b"glTF" + struct.pack("<II", 2, 40) + struct.pack("<II", 20, 0x4E4F534A) + b"{not json at all!!!}"
    dtc(lib, "Ball_B0BADJSON1_Corrupt", bad_json)
    expect["Ball_B0BADJSON1_Corrupt"] = "corrupt GLB: JSON chunk does not parse"

    dtc(lib, "Can_B0NOTMESH1_Text", b"just some text, certainly not a mesh\n" * 10)
    expect["Can_B0NOTMESH1_Text"] = "not a GLB file"
    (lib / "plain" / "photo.obj").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    expect["photo.obj"] = "no mesh data in file"
    (lib / "plain" / "noise.ply").write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 500, dtype=np.uint8)))
    expect["noise.ply"] = "cannot parse ply file"

    (lib / "plain" / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n")
    expect["points.obj"] = "mesh has no faces"
    (lib / "plain" / "empty.glb").write_bytes(b"")
    expect["empty.glb"] = "empty file (0 bytes)"

    # glTF whose texture file is missing, and an OBJ whose material points at a missing texture
    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    box.visual = trimesh.visual.TextureVisuals(
        uv=np.zeros((8, 2)), material=trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (4, 4)))
    )
    (lib / "plain" / "gl").mkdir()
    files = box.export(file_type="gltf")
    doc = json.loads(files["model.gltf"])
    doc["images"] = [{"uri": "albedo_missing.png"}]
    for name, data in files.items():
        (lib / "plain" / "gl" / name).write_bytes(data)
    (lib / "plain" / "gl" / "model.gltf").write_text(json.dumps(doc))
    expect["gl/model.gltf"] = "missing texture file: albedo_missing.png"
    # an OBJ whose material names a missing texture is no broken file: a default material, a flag
    obj_text = trimesh.creation.box(extents=(0.02, 0.02, 0.02)).export(file_type="obj")
    (lib / "plain" / "mug.obj").write_text("mtllib mug.mtl\nusemtl m\n" + obj_text)
    (lib / "plain" / "mug.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd textures/mug_albedo.jpg\n")

    # an unreadable folder: permissions when we are not root, a symlink loop when we are
    if os.geteuid() != 0:
        locked = dtc(lib, "Cup_B0LOCKED01_Shut", good)
        locked.chmod(0)
    else:
        os.symlink(lib / "Cup_B0LOCKED01_Shut", lib / "Cup_B0LOCKED01_Shut")
    expect["Cup_B0LOCKED01_Shut"] = "unreadable folder"

    # names with odd characters: a control character, and bytes that are not UTF-8
    dtc(lib, "Die_B0ODDNAME1_Line\nBreak", good)
    expect["Die_B0ODDNAME1_Line\\nBreak"] = "name has control or invisible characters"
    odd = os.path.join(os.fsencode(lib / "plain"), b"caf\xe9.glb")
    with open(odd, "wb") as fh:
        fh.write(good)
    expect["caf\\xe9.glb"] = "name is not valid UTF-8"

    # a huge file: sparse, so it costs no disk; it must be refused before it is read
    with open(lib / "plain" / "huge.glb", "wb") as fh:
        fh.truncate(600 * 2**20)
    expect["huge.glb"] = "file too large: 600.0 MB is over the limit of 512.0 MB"

    dtc(lib, "Toy_B0NOMODEL1_Missing")
    expect["Toy_B0NOMODEL1_Missing"] = "DTC folder has no 3d-asset.glb"
    return lib, expect


def test_every_bad_input_is_broken_with_a_specific_reason(bad_library, catalog):
    lib, expect = bad_library
    config = load_config([], ["ingest.workers=2"])
    summary = ingest_paths(catalog, [lib], config=config)
    with catalog.session() as s:
        objs = s.scalars(select(CatalogObject)).all()
    by_id = {o.source_id: o for o in objs}
    assert summary.new == 3  # the three good objects went through despite everything else
    assert summary.broken == len(expect) == len(objs) - 3
    for suffix, reason in expect.items():
        matches = [o for sid, o in by_id.items() if sid == suffix or sid.endswith("/" + suffix)]
        assert len(matches) == 1, (suffix, sorted(by_id))
        obj = matches[0]
        assert obj.status == "broken"
        assert reason in obj.error, (suffix, obj.error)
    mug = next(o for sid, o in by_id.items() if sid.endswith("/mug.obj"))
    with catalog.session() as s:
        flags = s.scalars(select(Flag).where(Flag.object_id == mug.id)).all()
    assert mug.status == "active" and [f.kind for f in flags] == ["missing_texture"]
    assert "textures/mug_albedo.jpg" in flags[0].reason
    good = by_id["Ball_B0GOOD0001_Red"]
    assert good.status == "active" and good.dims == pytest.approx((0.05, 0.05, 0.05))
    # a second run changes nothing and reports the same broken count
    again = ingest_paths(catalog, [lib], config=config)
    assert (again.new, again.updated, again.unchanged, again.broken) == (0, 0, 3, summary.broken)


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    # rich wraps stderr at 80 columns when it is not a terminal; a wide COLUMNS keeps messages whole
    env = {**os.environ, "COLUMNS": "400"}
    return subprocess.run([sys.executable, "-m", "mixcount", *args], cwd=PROJECT_ROOT, capture_output=True,
                          text=True, timeout=timeout, env=env)


@pytest.mark.slow
def test_cli_exit_codes_for_bad_inputs(bad_library, tmp_path):
    lib, expect = bad_library
    db = str(tmp_path / "cli.db")
    res = run_cli("--db", db, "catalog", "ingest", str(lib), "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["broken"] == len(expect) and summary["new"] == 3
    assert "broken Toy_B0NOMODEL1_Missing: DTC folder has no 3d-asset.glb" in res.stderr
    strict = run_cli("--db", db, "catalog", "ingest", str(lib), "--strict")
    assert strict.returncode != 0
    assert f"{len(expect)} broken object(s) (--strict)" in strict.stderr


def test_missing_path_and_unwritable_database_are_one_line_errors(tmp_path):
    good_glb(tmp_path / "ok.glb")
    res = run_cli("--db", str(tmp_path / "c.db"), "catalog", "ingest", str(tmp_path / "ok.glb"), str(tmp_path / "nope"))
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "path not found" in lines[0] and "nope" in lines[0]
    assert not (tmp_path / "c.db").exists()  # nothing was touched

    blocker = tmp_path / "not_a_dir"
    blocker.write_text("a file where the catalog folder should be")
    res = run_cli("--db", str(blocker / "catalog.db"), "catalog", "ingest", str(tmp_path / "ok.glb"))
    assert res.returncode != 0
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "error" in lines[0] and "catalog" in lines[0], res.stderr


def test_discover_rejects_missing_path(tmp_path):
    with pytest.raises(CatalogError, match="path not found"):
        discover([tmp_path / "missing"])
