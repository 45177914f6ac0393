"""Where each packaged file came from (mixcount.dataset.sources), without bpy: catalog rows pointing at
hand-made model files whose references stay in their library or leave it, each way a file can name
another (OBJ mtllib and maps, glTF buffers and images, GLB, USD sublayers and asset paths)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, IngestRun
from mixcount.dataset.sources import CatalogSources, model_references


def _gltf(path: Path, image_uri: str, buffer_uri: str = "mesh.bin") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": buffer_uri, "byteLength": 4}],
           "images": [{"uri": image_uri}, {"uri": "data:image/png;base64,AAAA"}]}
    path.write_text(json.dumps(doc))
    return path


def _obj(folder: Path, map_kd: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.mtl").write_text(f"newmtl a\nKd 1 0 0\nmap_Kd -s 1 1 1 {map_kd}\nbump {map_kd}\n")
    (folder / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n")
    return folder / "m.obj"


def _usda(path: Path, sublayer: str, texture: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'#usda 1.0\n(\n    subLayers = [@{sublayer}@]\n)\n\ndef "Tex" {{\n'
                    f'    asset inputs:file = @{texture}@\n}}\n')
    return path


@pytest.fixture
def library(tmp_path: Path) -> dict:
    lib, outside = tmp_path / "lib", tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.png").write_bytes(b"secret")
    (outside / "layer.usda").write_text("#usda 1.0\n")
    (lib / "textures").mkdir(parents=True)
    (lib / "textures" / "soda.png").write_bytes(b"soda")
    models = {
        "robosuite": _obj(lib / "objects" / "meshes", "../../textures/soda.png"),  # two folders up: inside
        "abs_map": _obj(lib / "abs", str(outside / "secret.png")),
        "gltf_escape": _gltf(lib / "g" / "a.gltf", "../../outside/secret.png"),
        "gltf_inside": _gltf(lib / "h" / "b.gltf", "tex.png"),
        "usd_out": _usda(lib / "u" / "c.usda", str(outside / "layer.usda"), "./tex.png"),
        "buffer_abs": _gltf(lib / "k" / "d.gltf", "tex.png", buffer_uri=f"file://{outside / 'secret.png'}"),
        "mtllib_out": _obj(lib / "m", "tex.png"),
        "linked_tex": _obj(lib / "n", "tex.png"),
    }
    # invented: an OBJ whose material library itself lies outside; a texture inside the library that is a
    # symbolic link to a file outside it
    (models["mtllib_out"]).write_text("mtllib ../../outside/x.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (outside / "x.mtl").write_text("newmtl a\nmap_Kd secret.png\n")
    (lib / "n" / "tex.png").symlink_to(outside / "secret.png")
    box = trimesh.creation.box()
    box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=np.tile([200, 0, 0, 255], (8, 1)))
    box.export(lib / "plain.glb")
    models["glb"] = lib / "plain.glb"
    stray = tmp_path / "stray" / "x.glb"
    stray.parent.mkdir()
    box.export(stray)
    models["stray"] = stray
    cat = open_catalog(f"sqlite:///{tmp_path / 'c.db'}", data_dir=str(tmp_path / "data"))
    with cat.session() as s:
        run = IngestRun(paths=json.dumps(["../lib"]))  # as typed, relative to a folder unknown now
        s.add(run)
        s.flush()
        for k, (name, model) in enumerate(models.items()):
            s.add(CatalogObject(source="folder", source_id=str(model), name=name, category="thing",
                                model_path=str(model), content_hash=f"{k:064x}", ingest_run_id=run.id))
        s.commit()
    yield {"catalog": cat, "lib": lib, "outside": outside, "keys": {n: f"{k:064x}" for k, n in enumerate(models)}}
    cat.close()


def test_references_each_format_names(library: dict) -> None:
    lib = library["lib"]
    refs = [r for r, _base in model_references(lib / "objects" / "meshes" / "m.obj")]
    assert refs == ["m.mtl", "../../textures/soda.png", "../../textures/soda.png"]  # options before the name dropped
    assert [r for r, _ in model_references(lib / "g" / "a.gltf")] == ["mesh.bin", "../../outside/secret.png"]
    assert model_references(lib / "plain.glb") == []  # embedded buffers and images name nothing
    usd = [Path(r).name for r, _ in model_references(lib / "u" / "c.usda")]
    assert "layer.usda" in usd and "tex.png" in usd


def test_verdicts_keep_what_stays_in_the_library_and_refuse_what_leaves(library: dict) -> None:
    keys = library["keys"]
    sources = CatalogSources(library["catalog"], [])
    ok = {name: sources.verdict(f"{keys[name]}.usdc", None) for name in keys}
    assert {n for n, v in ok.items() if v.ok} == {"robosuite", "gltf_inside", "glb"}
    soda = [s for s in ok["robosuite"].sources if s.path.endswith("soda.png")]
    assert soda and soda[0].library == "lib" and soda[0].path == "textures/soda.png"
    assert all(not Path(s.path).is_absolute() and str(library["lib"]) not in s.library_id
               for v in ok.values() for s in v.sources)
    assert "secret.png" in str(ok["abs_map"].refused) and "outside the library" in str(ok["abs_map"].refused)
    assert "../../outside/secret.png" in str(ok["gltf_escape"].refused)
    assert "layer.usda" in str(ok["usd_out"].refused)
    assert "lies in no library folder" in str(ok["stray"].refused)
    assert "file://" in str(ok["buffer_abs"].refused) and "../../outside/x.mtl" in str(ok["mtllib_out"].refused)
    assert "tex.png" in str(ok["linked_tex"].refused) and "outside the library" in str(ok["linked_tex"].refused)
    assert sources.verdict(f"{keys['abs_map']}_tex", None).refused  # the texture folder goes with its asset
    assert sources.verdict("deadbeef.usdc", None).why == "no object of this catalog"
    assert sources.verdict("notes/readme.txt", None).why == "not a library file"
    assert not sources.verdict("environments/sky.exr", library["outside"] / "secret.png").ok

    widened = CatalogSources(library["catalog"], [str(library["outside"])])  # the folder allowed now
    assert widened.verdict(f"{keys['abs_map']}.usdc", None).ok
    assert any(s.library == "outside" and s.path == "secret.png"
               for s in widened.verdict(f"{keys['gltf_escape']}.usdc", None).sources)


def test_a_file_dropped_into_the_assets_folder_is_taken_out_not_packaged(library: dict, tmp_path: Path) -> None:
    from mixcount.dataset.package import package_assets

    out = tmp_path / "out"
    (out / "scenes").mkdir(parents=True)
    (out / "assets" / "environments").mkdir(parents=True)
    (out / "assets" / "environments" / "evil.exr").write_bytes(b"not a map of this catalog")
    (out / "assets" / "notes.txt").write_bytes(b"nor this")
    report = package_assets(out, sources=CatalogSources(library["catalog"], []))
    assert [e for e, _line in report.refused] == ["environments/evil.exr", "notes.txt"] and report.bytes == 0
    assert not any(p.is_file() for p in (out / "assets").rglob("*"))
    listed = json.loads((out / "package.json").read_text())
    assert listed["files"] == [] and [r["why"] for r in listed["refused"]] == [
        "not an environment map of this catalog", "not a library file"]
