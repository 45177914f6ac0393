"""Damaged media and links out of the library, end to end (issue 68 items 1 and 3): ``catalog ingest-env`` and
``ingest-materials`` on hostile libraries built here from real files (bpy's studio-light EXRs, the Radiance
HDR in bpy's USD resources, matplotlib's sample JPEG / PNG), a model whose texture does not decode, and a
compose whose environment map was damaged after ingest (a real tiny Cycles render: black, so failed)."""

from __future__ import annotations

import json
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import select

from mixcount.catalog.pool_loader import load_environments, load_materials
from mixcount.config import load_config
from mixcount.scene.bundled_environments import bpy_package_dir, bundled_hdri_dir

MPL_DATA = Path(__import__("matplotlib").get_data_path()) / "sample_data"


def _cut(src: Path, dst: Path, keep: float) -> Path:
    dst.parent.mkdir(parents=True, exist_ok=True)
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * keep)])
    return dst


def _bomb_png(path: Path) -> Path:
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 40000, 40000, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + chunk(b"IEND", b""))
    return path


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    from mixcount.cli import main

    rc = main([*args, "--json"])
    out, err = capsys.readouterr()
    return rc, json.loads(out), err


def _rows(db_url: str, table: str) -> list[dict]:
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import Environment, Material

    model = {"environments": Environment, "materials": Material}[table]
    cat = open_catalog(db_url, data_dir="")
    try:
        with cat.session() as s:
            rows = [{"path": r.path, "broken": r.broken, "checked": r.checked_at is not None, "hash": r.content_hash}
                    for r in s.scalars(select(model).order_by(model.id))]
            drawn = load_environments(s) if table == "environments" else load_materials(s)
    finally:
        cat.close()
    return rows + [{"drawn": [d.path for d in drawn]}]


def test_ingest_env_records_damaged_maps_broken_and_refuses_links_out(tmp_path: Path, db_url: str,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    world = bundled_hdri_dir()
    beach = bpy_package_dir() / "lib" / "usd" / "hdx" / "resources" / "textures" / "StinsonBeach.hdr"
    lib, outside = tmp_path / "hdri", tmp_path / "elsewhere"
    (lib / "sub").mkdir(parents=True)
    outside.mkdir()
    shutil.copy(world / "night.exr", lib / "night.exr")
    shutil.copy(world / "studio.exr", lib / "sub" / "studio.exr")
    _cut(world / "forest.exr", lib / "sub" / "forest.exr", 0.6)  # the truncated EXR
    if beach.is_file():
        _cut(beach, lib / "beach.hdr", 0.5)  # a truncated Radiance HDR
    shutil.copy(world / "city.exr", outside / "secret.exr")
    os.symlink(outside / "secret.exr", lib / "linked.exr")  # a file link out
    os.symlink(outside, lib / "folder_out")  # a folder link out
    os.symlink(lib / "sub", lib / "again")  # a link inside: walked once
    os.symlink("..", lib / "sub" / "loop")  # a loop
    (lib / "notes.hdr").write_text("not a map")  # no HDR at all: skipped, as before
    secret_bytes = (outside / "secret.exr").read_bytes()

    rc, res, err = _main(capsys, "--db", db_url, "catalog", "ingest-env", str(lib))
    assert rc == 3, err  # items failed: PartialFailure's exit code
    broken = {Path(b["path"]).name: b["reason"] for b in res["broken"]}
    assert broken["forest.exr"].startswith("damaged OpenEXR: (EXR_ERR_BAD_CHUNK_LEADER)")
    if beach.is_file():
        assert broken["beach.hdr"] == "truncated Radiance HDR: the file ends inside a scanline"
    assert {Path(r["path"]).name for r in res["refused"]} == {"linked.exr", "folder_out"}
    assert all("leads outside the library" in r["reason"] and "--allow-root" in r["reason"] for r in res["refused"])
    assert res["new"] == 2 + len(broken) and res["skipped"] == [f"{lib / 'notes.hdr'}: not an HDR or EXR file"]
    assert f"failed: {lib / 'sub' / 'forest.exr'}: broken: damaged OpenEXR" in err
    assert f"failed: {lib / 'linked.exr'}: refused: link leads outside the library" in err
    assert "rerun only those: mixcount --db" in err and "Traceback" not in err

    *rows, drawn = _rows(db_url, "environments")
    assert all(Path(r["path"]).is_relative_to(lib) for r in rows)  # nothing from outside recorded
    assert all(r["checked"] for r in rows)
    assert {Path(r["path"]).name: r["broken"] for r in rows if r["broken"]} == broken
    assert sorted(Path(p).name for p in drawn["drawn"]) == ["night.exr", "studio.exr"]
    from mixcount.catalog.environments import _sha256

    assert _sha256([outside / "secret.exr"]) not in {r["hash"] for r in rows}
    assert not any(Path(r["path"]).read_bytes() == secret_bytes for r in rows)  # nor its bytes under another name

    # the sampler never draws a broken map
    from test_scene_distributions import rich_pool

    from mixcount.scene.object_records import EnvironmentRecord
    from mixcount.scene.sampler import sample_scene

    envs = [EnvironmentRecord(i + 1, Path(p).stem, p, "h") for i, p in enumerate(drawn["drawn"])]
    seen = {sample_scene(seed, "train", load_config(), rich_pool(), environments=envs).environment.path
            for seed in range(12)}
    assert seen == set(drawn["drawn"])

    # again: nothing new, the same failures; a row from before the check (checked_at NULL) is decoded now
    rc, again, _ = _main(capsys, "--db", db_url, "catalog", "ingest-env", str(lib))
    assert rc == 3 and again["new"] == 0 and {Path(b["path"]).name for b in again["broken"]} == set(broken)
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import Environment

    cat = open_catalog(db_url, data_dir="")
    with cat.session() as s:
        for row in s.scalars(select(Environment)):
            row.broken, row.checked_at = None, None  # as a catalog ingested before migration 0009 has them
        s.commit()
        assert len(load_environments(s)) == len(rows)
    cat.close()
    rc, old, _ = _main(capsys, "--db", db_url, "catalog", "ingest-env", str(lib))
    assert rc == 3 and {Path(b["path"]).name for b in old["broken"]} == set(broken)
    assert sorted(Path(p).name for p in _rows(db_url, "environments")[-1]["drawn"]) == ["night.exr", "studio.exr"]

    # the user allows the outside folder: its map is read and recorded
    rc, allowed, _ = _main(capsys, "--db", db_url, "catalog", "ingest-env", str(lib), "--allow-root", str(outside))
    assert allowed["refused"] == [] and allowed["new"] == 1
    assert any(Path(p).name == "secret.exr" for p in _rows(db_url, "environments")[-1]["drawn"])


def test_ingest_materials_records_damaged_sets_broken_and_refuses_links_out(tmp_path: Path, db_url: str,
                                                                           capsys: pytest.CaptureFixture[str]) -> None:
    lib, outside = tmp_path / "materials", tmp_path / "elsewhere"
    outside.mkdir()
    good = lib / "Fabric_01"
    good.mkdir(parents=True)
    shutil.copy(MPL_DATA / "grace_hopper.jpg", good / "Fabric_01_Color.jpg")
    shutil.copy(MPL_DATA / "logo2.png", good / "Fabric_01_Roughness.png")
    _cut(MPL_DATA / "grace_hopper.jpg", lib / "Cut_02" / "Cut_02_Color.jpg", 0.7)  # truncated base colour
    shutil.copy(MPL_DATA / "logo2.png", lib / "Cut_02" / "Cut_02_Roughness.png")
    (lib / "Bomb_03").mkdir()
    shutil.copy(MPL_DATA / "grace_hopper.jpg", lib / "Bomb_03" / "Bomb_03_Color.jpg")
    _bomb_png(lib / "Bomb_03" / "Bomb_03_NormalGL.png")  # a normal map declaring 40000 x 40000
    (lib / "Linked_04").mkdir()
    shutil.copy(MPL_DATA / "Minduka_Present_Blue_Pack.png", outside / "secret.png")
    os.symlink(outside / "secret.png", lib / "Linked_04" / "Linked_04_Color.png")  # its base colour links out

    rc, res, err = _main(capsys, "--db", db_url, "catalog", "ingest-materials", str(lib))
    assert rc == 3, err
    broken = {Path(b["path"]).name: b["reason"] for b in res["broken"]}
    assert broken["Cut_02"].startswith("base_color map Cut_02_Color.jpg: damaged jpeg: image file is truncated")
    assert broken["Bomb_03"].startswith("normal map Bomb_03_NormalGL.png: declares 1,600,000,000 pixels, over the limit")
    assert [Path(r["path"]).name for r in res["refused"]] == ["Linked_04_Color.png"]
    *rows, drawn = _rows(db_url, "materials")
    assert [Path(p).name for p in drawn["drawn"]] == ["Fabric_01"]
    assert {Path(r["path"]).name for r in rows} == {"Fabric_01", "Cut_02", "Bomb_03"}  # Linked_04: no base colour left
    assert all(Path(r["path"]).is_relative_to(lib) for r in rows)
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import Material

    cat = open_catalog(db_url, data_dir="")
    with cat.session() as s:
        maps = [json.loads(m.maps_json) for m in s.scalars(select(Material))]
    cat.close()
    assert not any("elsewhere" in p or "secret" in p for m in maps for p in m.values())

    from test_scene_distributions import rich_pool

    from mixcount.scene.object_records import MaterialRecord
    from mixcount.scene.sampler import sample_scene

    conf = load_config([], ["scene.procedural_floor_probability=0.0"])
    mats = [MaterialRecord(1, "Fabric_01", drawn["drawn"][0], {"base_color": str(good / "Fabric_01_Color.jpg")})]
    for seed in range(6):
        floor = sample_scene(seed, "train", conf, rich_pool(), materials=mats).floor
        assert floor.material.kind == "pbr" and floor.material.maps["base_color"].endswith("Fabric_01_Color.jpg")


def _textured_box_library(root: Path) -> dict[str, Path]:
    """Four OBJ boxes with UVs whose MTL names one texture each: whole, truncated, lying about its size, a
    declared 40000 x 40000 PNG."""
    import trimesh
    from PIL import Image

    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    box.unmerge_vertices()
    uv = np.random.default_rng(0).random((len(box.vertices), 2))
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.open(MPL_DATA / "logo2.png").convert("RGB"))
    text, _ = trimesh.exchange.obj.export_obj(box, include_texture=True, return_texture=True, mtl_name="box.mtl")
    png = (MPL_DATA / "logo2.png").read_bytes()
    lie = bytearray(png)
    lie[16:24] = struct.pack(">II", 4000, 4000)
    lie[29:33] = struct.pack(">I", zlib.crc32(b"IHDR" + bytes(lie[16:29])))
    textures = {"whole": png, "cut": png[: len(png) // 2], "liar": bytes(lie), "bomb": None}
    out = {}
    for name, data in textures.items():
        folder = root / name
        folder.mkdir(parents=True)
        (folder / "box.obj").write_text(text)
        (folder / "box.mtl").write_text("newmtl material_0\nKd 0.8 0.8 0.8\nmap_Kd tex.png\n")
        if data is None:
            _bomb_png(folder / "tex.png")
        else:
            (folder / "tex.png").write_bytes(data)
        out[name] = folder
    return out


def test_a_model_texture_that_does_not_decode_flags_the_object_and_is_never_rendered(
        tmp_path: Path, db_url: str, capsys: pytest.CaptureFixture[str]) -> None:
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject, Flag, Render

    _textured_box_library(tmp_path / "lib")
    rc, res, err = _main(capsys, "--db", db_url, "catalog", "ingest", str(tmp_path / "lib"))
    assert rc == 0 and res["new"] == 4, err
    cat = open_catalog(db_url, data_dir="")
    with cat.session() as s:
        objs = {o.name: o for o in s.scalars(select(CatalogObject))}
        flags = {objs_name: [(f.kind, f.reason) for f in s.scalars(select(Flag).where(Flag.object_id == o.id))]
                 for objs_name, o in objs.items()}
    cat.close()
    assert all(o.status == "active" for o in objs.values())  # kept: the geometry is whole
    assert flags["whole"] == []
    assert flags["cut"] == [("damaged_texture", "texture tex.png does not decode: damaged png: image file is truncated")]
    assert flags["liar"][0][0] == "damaged_texture" and "damaged png" in flags["liar"][0][1]
    assert flags["bomb"] == [("damaged_texture", "texture tex.png does not decode: declares 1,600,000,000 pixels, "
                              "over the limit of 67,108,864 ([ingest] max_image_pixels); not decoded (Pillow's "
                              "decompression-bomb check)")]
    assert "warning: cut: texture tex.png does not decode: damaged png" in err
    # scenes never draw them (their USD conversion would stop on the image, Blender would paint it)
    from mixcount.catalog.models import Split
    from mixcount.catalog.pool_loader import damaged_texture_note, load_pool

    cat = open_catalog(db_url, data_dir="")
    with cat.session() as s:
        s.add_all([Split(object_id=o.id, split="train", method="random") for o in objs.values()])
        s.commit()
        assert [o.name for o in load_pool(s, split="train")] == ["whole"]
        note = damaged_texture_note(s, "train")  # and a run says so at its start
        assert damaged_texture_note(s, "test") is None
    cat.close()
    assert note is not None and note.startswith("3 object(s) of split 'train' are left out of scenes because a "
                                                "texture did not decode at ingest (bomb, cut, liar;")
    dry = __import__("mixcount.cli", fromlist=["main"]).main(
        ["--db", db_url, "--config", "quick", "compose", "--n", "1", "--split", "train", "--dry-run",
         "--out", str(tmp_path / "dry")])
    assert dry == 0 and note in " ".join(capsys.readouterr().err.split())

    # canonical renders: the three are not sent to Blender (it painted them black, and spent 78 s on the bomb)
    rc = __import__("mixcount.cli", fromlist=["main"]).main(
        ["--db", db_url, "--set", "canonical_render.resolution=48", "--set", "canonical_render.samples=1",
         "--set", "canonical_render.denoise=false", "catalog", "render"])
    out, err = capsys.readouterr()
    assert rc == 3, out + err
    assert "render: 4 objects, 1 rendered, 0 up to date, 3 failed" in out
    assert f"failed: #{objs['bomb'].id} bomb: not rendered: texture tex.png does not decode: declares" in err
    cat = open_catalog(db_url, data_dir="")
    with cat.session() as s:
        renders = {r.object_id: (r.path, r.error) for r in s.scalars(select(Render))}
    cat.close()
    assert renders[objs["whole"].id][0] and Path(renders[objs["whole"].id][0]).is_file()
    for name in ("cut", "liar", "bomb"):
        path, error = renders[objs[name].id]
        assert path is None and error.startswith("not rendered: texture tex.png does not decode")


@pytest.mark.blender
@pytest.mark.slow
def test_compose_with_an_environment_damaged_after_ingest_fails_its_scenes(
        tmp_path: Path, demo_catalog_copy, capsys: pytest.CaptureFixture[str]) -> None:
    """The map decoded whole at ingest and was cut afterwards (a copy finished later, a disk error): Blender
    reads what is left and the render comes out black (mean 0.09 of 255, the issue's 0.1), so each scene is
    failed with the reason and not written, and compose exits 3 instead of "0 failed", exit 0. (A map cut
    after some whole chunks can light a scene from the part that is left: only the ingest decode sees it.)"""
    from mixcount.cli import main

    root = demo_catalog_copy(tmp_path / "cat", 12)
    db = str(root / "catalog.db")
    hdri = tmp_path / "hdri" / "sunset.exr"
    hdri.parent.mkdir()
    shutil.copy(bundled_hdri_dir() / "sunset.exr", hdri)
    assert main(["--db", db, "catalog", "ingest-env", str(hdri.parent)]) == 0
    capsys.readouterr()
    _cut(bundled_hdri_dir() / "sunset.exr", hdri, 0.02)  # only its header is left
    out = tmp_path / "out"
    rc = main(["--db", db, "--config", "quick", "--set", "compose.render_threads=2", "--set", "compose.samples=1",
               "--set", "scene.n_objects=[2,3]", "--set", "scene.n_classes=[1,1]", "--set", "scene.n_distractors=[0,0]",
               "--set", "scene.physics_frames=10", "--set", "compose.max_attempts_factor=0.0",
               "compose", "--n", "1", "--seed", "3", "--resolution", "32", "--no-merge", "--out", str(out)])
    stdout, stderr = capsys.readouterr()
    assert rc == 3, stdout + stderr
    logged = [json.loads(x) for x in (out / "logs" / "failures.jsonl").read_text().splitlines()]
    assert logged and {x["cause"] for x in logged} == {"error: RenderError"}
    assert f"already there, {len(logged)} failed" in stdout and "already there, 0 failed" not in stdout
    for x in logged:
        seed = x["seed"]
        assert (f"failed: scene_{seed:06d} (seed {seed}): [error: RenderError] RenderError: scene scene_{seed:06d}: "
                "rgb.png: the render is black (mean 0.0") in stderr
        assert not (out / "scenes" / f"scene_{seed:06d}").exists()  # a black render is never written
    assert "Traceback" not in stderr
    # Blender lit the third scene of its worker with a plain world (mean 115 of 255) though the dome texture
    # cannot be read: that render is no black one and is written; only the ingest decode sees every such map
    from PIL import Image

    for scene in (d for d in (out / "scenes").iterdir() if not d.name.startswith(".")):
        assert np.asarray(Image.open(scene / "rgb.png").convert("RGB")).mean() > 1.0
