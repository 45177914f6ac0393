"""A model's texture in a folder beside the model's own (robosuite ships ``objects/meshes/can.mtl`` naming
``../../textures/soda.png``) is read by ingest, the USD conversion and the caption colours, as Blender and
MuJoCo read it. trimesh refuses such a path unless told otherwise, and the models came out untextured
without a word (``mixcount.frame.load_model``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.captions.colours import colours_from_model
from mixcount.catalog.db import open_catalog
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject
from mixcount.config import load_config
from mixcount.frame import load_model
from mixcount.usd.assets import convert_asset


def _shipped_like_robosuite(root: Path) -> Path:
    """``objects/meshes/can.obj`` + ``can.mtl`` whose texture sits in ``textures/`` two folders up."""
    meshes, textures = root / "objects" / "meshes", root / "textures"
    meshes.mkdir(parents=True)
    textures.mkdir()
    can = trimesh.creation.cylinder(radius=0.03, height=0.12, sections=24)
    uv = np.c_[(np.arctan2(can.vertices[:, 1], can.vertices[:, 0]) + np.pi) / (2 * np.pi), can.vertices[:, 2] + 0.5]
    can.visual = trimesh.visual.TextureVisuals(
        uv=uv, material=trimesh.visual.material.SimpleMaterial(image=Image.new("RGB", (16, 16), (200, 20, 30))))
    can.export(meshes / "can.obj")
    pngs = sorted(meshes.glob("*.png"))
    assert pngs, "trimesh wrote no texture beside the OBJ"
    pngs[0].rename(textures / "soda.png")
    mtl = meshes / "material.mtl" if (meshes / "material.mtl").exists() else next(meshes.glob("*.mtl"))
    text = mtl.read_text()
    mtl.write_text("\n".join("map_Kd ../../textures/soda.png" if ln.startswith("map_Kd") else ln
                             for ln in text.splitlines()) + "\n")
    return meshes / "can.obj"


def test_a_texture_in_a_sibling_folder_is_read_everywhere(tmp_path: Path) -> None:
    model = _shipped_like_robosuite(tmp_path / "lib")
    scene = load_model(model, force="scene")
    assert [g.visual.material.image is not None for g in scene.geometry.values()] == [True]

    catalog = open_catalog(f"sqlite:///{tmp_path / 'c.db'}", data_dir=str(tmp_path / "data"))
    try:
        summary = ingest_paths(catalog, [tmp_path / "lib"], config=load_config())  # the library: lib/
        assert summary.new == 1 and summary.broken == 0 and not summary.refused
        with catalog.session() as s:
            obj = s.scalars(select(CatalogObject)).one()
            assert obj.textured and obj.name == "can"
    finally:
        catalog.close()
    # lib/objects named as the library: the texture in lib/textures is outside it, refused (issue 68)
    # with a flag that names it, unless --allow-root names its folder
    for extra, textured in (((), False), ((tmp_path / "lib" / "textures",), True)):
        other = open_catalog(f"sqlite:///{tmp_path / f'o{len(extra)}.db'}", data_dir=str(tmp_path / f"o{len(extra)}"))
        try:
            summary = ingest_paths(other, [tmp_path / "lib" / "objects"], config=load_config(), allow_roots=extra)
            assert summary.new == 1 and summary.broken == 0
            said = [w for _n, w in summary.warnings if "soda.png" in w and "outside the library" in w]
            assert bool(said) != textured, summary.warnings
            with other.session() as s:
                assert s.scalars(select(CatalogObject)).one().textured == textured
        finally:
            other.close()

    paths = convert_asset(model, tmp_path / "usd", content_hash="x", units="m", up_axis="Z")
    written = list(Path(paths.visual).parent.glob("*_tex/*"))
    assert written, "the USD asset carries no texture"
    assert "red" in colours_from_model(model).names
