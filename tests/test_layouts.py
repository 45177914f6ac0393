"""Library layouts, ingested for real: a generated tree of each layout people have (Digital Twin Catalog,
Google Scanned Objects, Objaverse / Amazon Berkeley Objects with side metadata in JSON, JSONL and CSV,
OmniObject3D, plain folders) goes into an alembic-migrated SQLite catalog with the names, categories
and licences its metadata gives, textures found, units and up axes right; ``layout`` forces a reading."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.layouts import discover, parse_pbtxt
from mixcount.catalog.models import CatalogObject
from mixcount.cli import main
from mixcount.config import load_config


def cfg():
    return load_config([])


def rows(catalog) -> dict[str, CatalogObject]:
    with catalog.session() as s:
        return {o.name: o for o in s.scalars(select(CatalogObject))}


def textured(mesh: trimesh.Trimesh, colour=(200, 40, 40)) -> trimesh.Trimesh:
    uv = np.c_[mesh.vertices[:, 0] > mesh.vertices[:, 0].mean(), mesh.vertices[:, 2] > mesh.vertices[:, 2].mean()]
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (8, 8), colour))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv.astype(float), material=mat)
    return mesh


def write_obj(obj: Path, mesh: trimesh.Trimesh, *, mtl_name: str, texture_ref: str) -> None:
    """An OBJ with per-vertex UVs and an MTL whose map_Kd names ``texture_ref`` (the way GSO and
    OmniObject3D ship them)."""
    obj.parent.mkdir(parents=True, exist_ok=True)
    uv = np.c_[(mesh.vertices[:, 0] - mesh.vertices[:, 0].min()) / np.ptp(mesh.vertices[:, 0]),
               (mesh.vertices[:, 1] - mesh.vertices[:, 1].min()) / np.ptp(mesh.vertices[:, 1])]
    lines = [f"mtllib {mtl_name}"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv] + ["usemtl material_0"]
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in mesh.faces]
    obj.write_text("\n".join(lines) + "\n")
    (obj.parent / mtl_name).write_text(f"newmtl material_0\nKa 1 1 1\nKd 1 1 1\nmap_Kd {texture_ref}\n")


def texture(path: Path, colour) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (16, 16), colour).save(path)


# --------------------------------------------------------------------------- the trees


def dtc_tree(root: Path) -> None:
    folder = root / "Mugs_B07Z5P84J2_Red"
    folder.mkdir(parents=True)
    textured(trimesh.creation.cylinder(radius=0.04, height=0.1)).export(folder / "3d-asset.glb")
    (folder / "metadata.json").write_text(json.dumps({"category": "Mugs", "name": "Red mug"}))
    (folder / "LICENSE").write_text("CC-BY-4.0 (DTC)")
    # a DTC folder whose model is not called 3d-asset.glb: the model that is there is used
    other = root / "Bowls_B0AAAAAAA1_Blue"
    other.mkdir()
    trimesh.creation.cylinder(radius=0.07, height=0.05).export(other / "bowl_scan.glb")
    (other / "metadata.json").write_text(json.dumps({"category": "bowl"}))


GSO_PBTXT = '''name: "Threshold_Porcelain_Teapot_White"
version: 2
description: "Threshold Porcelain Teapot, White"
license: "Creative Commons Attribution 4.0 International"
authors {
  name: "Google"
  email: "scanned-objects@google.com"
}
categories: "Kitchen"
annotations {
  key: "color"
  value: "white"
}
'''


def gso_tree(root: Path) -> None:
    teapot = root / "Threshold_Porcelain_Teapot_White"
    write_obj(teapot / "meshes" / "model.obj", trimesh.creation.box(extents=(0.2, 0.1, 0.15)),
              mtl_name="model.mtl", texture_ref="texture.png")
    texture(teapot / "materials" / "textures" / "texture.png", (230, 230, 240))
    (teapot / "metadata.pbtxt").write_text(GSO_PBTXT)
    (teapot / "model.config").write_text("<?xml version='1.0'?><model><name>teapot</name></model>\n")
    (teapot / "model.sdf").write_text("<sdf version='1.7'></sdf>\n")
    texture(teapot / "thumbnails" / "0.jpg", (10, 10, 10))
    shoe = root / "ASICS_GELResolution_5_Flash_Yellow"  # no category in its metadata: the name gives one
    write_obj(shoe / "meshes" / "model.obj", trimesh.creation.box(extents=(0.3, 0.1, 0.12)),
              mtl_name="model.mtl", texture_ref="texture.png")
    texture(shoe / "materials" / "textures" / "texture.png", (250, 220, 20))
    (shoe / "metadata.pbtxt").write_text('name: "ASICS_GELResolution_5_Flash_Yellow"\n'
                                         'legal { license: "CC-BY 4.0" }\ncategories: "None"\n')


def objaverse_tree(root: Path) -> dict[str, str]:
    uids = {"8476c4170df24cf5bbe6967222d1a42d": "Wooden Serving Tray", "0a1b2c3d4e5f60718293a4b5c6d7e8f9":
            "Ceramic Coffee Mug", "ffeeddccbbaa99887766554433221100": "Red Apple"}
    for k, uid in enumerate(uids):
        path = root / "glbs" / f"000-00{k}" / f"{uid}.glb"
        path.parent.mkdir(parents=True)
        textured(trimesh.creation.icosphere(subdivisions=2, radius=0.05 + 0.01 * k)).export(path)
    ann = {uid: {"uid": uid, "name": name, "license": "by", "categories": [{"name": "food-drink"}] if k == 2 else [],
                 "tags": [{"name": "kitchen"}]} for k, (uid, name) in enumerate(uids.items())}
    (root / "metadata").mkdir()
    with gzip.open(root / "metadata" / "000-000.json.gz", "wt") as fh:
        json.dump(ann, fh)
    return uids


def abo_tree(root: Path) -> Path:
    """ABO: 3dmodels/original/<d>/<3dmodel_id>.glb, listings JSONL.gz elsewhere, one licence at the root."""
    model = root / "3dmodels" / "original" / "0" / "B07QH3W7SB.glb"
    model.parent.mkdir(parents=True)
    textured(trimesh.creation.box(extents=(0.3, 0.2, 0.02))).export(model)
    listings = root / "listings" / "metadata" / "listings_0.json.gz"
    listings.parent.mkdir(parents=True)
    with gzip.open(listings, "wt") as fh:
        fh.write(json.dumps({"item_id": "B07XYZ", "3dmodel_id": "B07QH3W7SB", "product_type": [{"value": "TRAY"}],
                             "item_name": [{"language_tag": "de_DE", "value": "Holztablett"},
                                           {"language_tag": "en_US", "value": "Rivet Wooden Serving Tray"}]}) + "\n")
        fh.write(json.dumps({"item_id": "B0OTHER", "item_name": [{"language_tag": "en_US", "value": "Lamp"}]}) + "\n")
    (root / "LICENSE-CC-BY-NC-4.0.txt").write_text("Attribution-NonCommercial 4.0 International (CC BY-NC 4.0)")
    return listings


def csv_tree(root: Path) -> None:
    (root / "models").mkdir(parents=True)
    textured(trimesh.creation.cylinder(radius=0.1, height=0.02)).export(root / "models" / "obj_0001.glb")
    (root / "index.csv").write_text("uid,name,category,license\nobj_0001,Blue Dinner Plate,plate,CC0\n")


def omni_tree(root: Path) -> None:
    for cat, n, size in (("apple", 1, (80.0, 75.0, 70.0)), ("toy_truck", 2, (150.0, 60.0, 70.0))):
        scan = root / "raw_scans" / cat / f"{cat}_{n:03d}" / "Scan"
        write_obj(scan / "Scan.obj", trimesh.creation.box(extents=size), mtl_name="Scan.mtl", texture_ref="Scan.jpg")
        texture(scan / "Scan.jpg", (200, 30, 30))
    (root / "LICENSE").write_text("CC BY 4.0 (OmniObject3D)")


def plain_tree(root: Path) -> None:
    teapot = root / "teapot-blue"
    teapot.mkdir(parents=True)
    textured(trimesh.creation.icosphere(subdivisions=2, radius=0.08)).export(teapot / "Teapot_final_v2.glb")
    (teapot / "metadata.json").write_text(json.dumps({"name": "Blue Teapot", "license": "CC0-1.0", "units": "m"}))
    lamp = root / "desk_lamp"
    lamp.mkdir()
    trimesh.creation.cone(radius=0.1, height=0.3).export(lamp / "model.glb")
    (lamp / "LICENSE.txt").write_text("MIT")
    loose = root / "loose"
    loose.mkdir()
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(loose / "block_01.glb")
    trimesh.creation.icosphere(radius=0.03).export(loose / "ball_03.glb")


# --------------------------------------------------------------------------- tests


def test_every_layout_in_one_tree_names_categories_licences(tmp_path, catalog):
    lib = tmp_path / "library"
    dtc_tree(lib / "dtc")
    gso_tree(lib / "gso")
    uids = objaverse_tree(lib / "objaverse")
    csv_tree(lib / "objaverse_csv")
    omni_tree(lib / "omniobject3d")
    plain_tree(lib / "plain")
    abo_listings = abo_tree(tmp_path / "abo")

    summary = ingest_paths(catalog, [lib, tmp_path / "abo"], config=load_config([], ["ingest.workers=2"]), metadata_files=[abo_listings])
    assert summary.broken == 0, summary.broken_objects
    assert summary.layouts == {"dtc": 2, "gso": 2, "objaverse": 5, "omniobject3d": 2, "folder": 4}
    objs = rows(catalog)
    expect = {  # name: (source, category, licence fragment or None)
        "Mugs_B07Z5P84J2_Red": ("dtc", "mug", "CC-BY-4.0 (DTC)"),
        "Bowls_B0AAAAAAA1_Blue": ("dtc", "bowl", None),
        "Threshold_Porcelain_Teapot_White": ("gso", "kitchen", "Creative Commons Attribution 4.0 International"),
        "ASICS_GELResolution_5_Flash_Yellow": ("gso", "flash", "CC-BY 4.0"),
        "Wooden Serving Tray": ("objaverse", "tray", "CC BY 4.0"),
        "Ceramic Coffee Mug": ("objaverse", "mug", "CC BY 4.0"),
        "Red Apple": ("objaverse", "food-drink", "CC BY 4.0"),
        "Rivet Wooden Serving Tray": ("objaverse", "tray", "CC BY-NC 4.0"),
        "Blue Dinner Plate": ("objaverse", "plate", "CC0"),
        "apple_001": ("omniobject3d", "apple", "CC BY 4.0 (OmniObject3D)"),
        "toy_truck_002": ("omniobject3d", "toy truck", "CC BY 4.0 (OmniObject3D)"),
        "Blue Teapot": ("folder", "teapot", "CC0-1.0"),
        "desk_lamp": ("folder", "lamp", "MIT"),
        "block_01": ("folder", "block", None),
        "ball_03": ("folder", "ball", None),
    }
    assert set(objs) == set(expect)
    for name, (source, category, licence) in expect.items():
        o = objs[name]
        assert (o.source, o.category, o.status) == (source, category, "active"), (name, o.source, o.category, o.error)
        if licence is None:
            assert o.license is None, name
        else:
            assert licence in (o.license or ""), (name, o.license)
    # ids: the uid for Objaverse/ABO records, the folder for GSO, category/object for OmniObject3D
    assert objs["Ceramic Coffee Mug"].source_id in uids
    assert objs["Rivet Wooden Serving Tray"].source_id == "B07QH3W7SB"
    assert objs["apple_001"].source_id == "apple/apple_001"
    assert objs["Threshold_Porcelain_Teapot_White"].source_id == "Threshold_Porcelain_Teapot_White"

    # GSO: the texture in materials/textures is found (staged copy), metres, Z-up kept as it is
    teapot = objs["Threshold_Porcelain_Teapot_White"]
    assert teapot.textured and teapot.source_units == "m" and teapot.source_up_axis == "Z"
    assert teapot.dims == pytest.approx((0.2, 0.1, 0.15), abs=1e-5)
    staged = Path(teapot.model_path)
    assert staged.is_relative_to(catalog.data_dir / "staged") and (staged.parent / "texture.png").is_file()
    meta = json.loads(teapot.metadata_json)
    assert meta["metadata"]["source_model_path"].endswith("meshes/model.obj")
    assert meta["metadata"]["description"] == "Threshold Porcelain Teapot, White" and meta["ingest"]["layout"] == "gso"
    # OmniObject3D: millimetres (ingest.omniobject3d_units), Y-up turned Z-up, textured
    apple = objs["apple_001"]
    assert apple.source_units == "mm" and apple.textured
    assert apple.dims == pytest.approx((0.08, 0.07, 0.075), abs=1e-5)
    # the record a name came from is kept
    record = json.loads(objs["Rivet Wooden Serving Tray"].metadata_json)["metadata"]
    assert record["record"]["3dmodel_id"] == "B07QH3W7SB" and record["metadata_file"].endswith("listings_0.json.gz")

    # rerun: nothing changes; a changed record is a metadata-only update of the same row
    again = ingest_paths(catalog, [lib, tmp_path / "abo"], config=load_config([], ["ingest.workers=2"]), metadata_files=[abo_listings])
    assert (again.unchanged, again.new, again.updated, again.broken) == (summary.total, 0, 0, 0)
    (lib / "objaverse_csv" / "index.csv").write_text("uid,name,category,license\nobj_0001,Blue Platter,platter,CC0\n")
    third = ingest_paths(catalog, [lib, tmp_path / "abo"], config=load_config([], ["ingest.workers=2"]), metadata_files=[abo_listings])
    assert (third.updated, third.new) == (1, 0)
    renamed = rows(catalog)["Blue Platter"]
    assert renamed.id == objs["Blue Dinner Plate"].id and renamed.category == "platter"


def test_folder_with_metadata_json_and_other_model_name_is_not_dtc(tmp_path, catalog):
    """The library of the issue: <name>/model.glb + metadata.json + licence must not be read as DTC."""
    lib = tmp_path / "lib"
    for name, category in (("microwave", "Appliances"), ("handbag", "Bags")):
        folder = lib / name
        folder.mkdir(parents=True)
        trimesh.creation.box(extents=(0.3, 0.2, 0.2)).export(folder / "model.glb")
        (folder / "metadata.json").write_text(json.dumps({"name": name.title(), "category": category}))
        (folder / "LICENSE").write_text("CC-BY-4.0")
    summary = ingest_paths(catalog, [lib], config=load_config([], ["ingest.workers=1"]))
    assert (summary.new, summary.broken) == (2, 0), summary.broken_objects
    objs = rows(catalog)
    assert objs["Microwave"].category == "appliance" and objs["Handbag"].category == "bag"
    assert all(o.source == "folder" and o.license == "CC-BY-4.0" for o in objs.values())


def test_layout_override(tmp_path, catalog, capsys):
    lib = tmp_path / "lib"
    plain_tree(lib)
    gso_like = lib / "not_gso"
    gso_like.mkdir()
    (gso_like / "metadata.pbtxt").write_text('name: "half a GSO folder"\n')
    # auto: plain folders; forced gso: the pbtxt folder is a GSO object without its mesh
    auto = {c.name: c for c in discover([lib])}
    assert {c.layout for c in auto.values()} == {"folder"}
    forced = {c.source_id: c for c in discover([lib], layout="gso")}
    assert forced["not_gso"].error == "GSO folder has no meshes/model.obj"
    # forced dtc: each leaf folder is a DTC object named by its folder
    dtc = {c.name: c for c in discover([lib], layout="dtc")}
    assert dtc["desk_lamp"].source == "dtc" and dtc["teapot-blue"].model_path.name == "Teapot_final_v2.glb"
    # forced objaverse: every model file is an object keyed by its file stem, even without a record
    obj = {c.source_id: c for c in discover([lib], layout="objaverse")}
    assert obj["model"].source == "objaverse" and obj["model"].metadata == {"record": None}

    db = str(tmp_path / "cli.db")
    assert main(["--db", db, "catalog", "ingest", str(lib), "--layout", "gso", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["broken"] == 1 and out["broken_objects"][0]["reason"] == "GSO folder has no meshes/model.obj"
    assert main(["--db", db, "catalog", "ingest", str(lib), "--layout", "nonsense"]) != 0
    assert "unknown layout 'nonsense'" in capsys.readouterr().err


def test_dtc_folder_without_an_id_takes_its_leading_category(tmp_path):
    """DTC names put the category first; without an id the variant's last word is not the noun."""
    for name in ("Apple_granny_smith", "Teapot-blue_glazed"):
        folder = tmp_path / "dtc" / name
        folder.mkdir(parents=True)
        trimesh.creation.box().export(folder / "3d-asset.glb")
    found = {c.name: c.category for c in discover([tmp_path / "dtc"], layout="dtc")}
    assert found == {"Apple_granny_smith": "apple", "Teapot-blue_glazed": "teapot"}


def test_pbtxt_parser():
    doc = parse_pbtxt(GSO_PBTXT + 'tags: ["a", "b"]\n# a comment\nlegal < license: "x" "y" >\n')
    assert doc["name"] == ["Threshold_Porcelain_Teapot_White"] and doc["version"] == [2]
    assert doc["authors"][0]["email"] == ["scanned-objects@google.com"]
    assert doc["annotations"][0] == {"key": ["color"], "value": ["white"]}
    assert doc["tags"] == ["a", "b"] and doc["legal"][0]["license"] == ["xy"]
    with pytest.raises(ValueError):
        parse_pbtxt("name: {")
