"""The model's albedo as the renderer evaluates it (issue 57 item 4), the rules found on held-out
assimp-testmodels files: a glTF ``baseColorFactor`` and an .mtl ``Kd`` are linear (0.85 renders white, not
light grey), a glTF material without a factor has glTF's default 1 (trimesh's ``main_color`` is a made-up
0.4 grey: BoxTexcoords read "grey and dark green" against a white-and-green render), and an .mtl ``Kd``
beside a ``map_Kd`` is not applied (Blender's OBJ importer renders the map alone), in captions and in the
USD asset alike."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial, SimpleMaterial

from mixcount.captions.colours import colours_from_model
from mixcount.catalog.materials import base_colour_factor
from mixcount.usd.model_parts import load_parts


def _box(path: Path, material, texture: bool) -> Path:
    mesh = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2)) if texture else None
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    mesh.export(path)
    return path


def test_linear_factor_named_as_rendered(tmp_path):
    glb = _box(tmp_path / "white.glb", PBRMaterial(baseColorFactor=[0.85, 0.85, 0.85, 1.0]), texture=False)
    assert colours_from_model(glb).names == ("white",)  # sRGB 0.93; read as 0.85 sRGB it was "light grey"
    red = _box(tmp_path / "red.glb", PBRMaterial(baseColorFactor=[0.6, 0.02, 0.02, 1.0]), texture=False)
    assert colours_from_model(red).names == ("red",)


def test_gltf_without_factor_and_obj_kd_beside_a_map(tmp_path):
    green = Image.fromarray(np.tile(np.array([40, 170, 60], dtype=np.uint8), (8, 8, 1)))
    glb = _box(tmp_path / "tex.glb", PBRMaterial(baseColorTexture=green), texture=True)
    loaded = trimesh.load(glb, force="mesh")
    assert loaded.visual.material.baseColorFactor is None
    np.testing.assert_allclose(base_colour_factor(loaded.visual), 1.0)
    assert colours_from_model(glb).names == ("green",)
    assert load_parts(glb, 1.0, "Y")[0].material["base_color_factor"] == [1.0, 1.0, 1.0, 1.0]
    obj = _box(tmp_path / "duck.obj", SimpleMaterial(image=green, diffuse=[163, 163, 163, 255]), texture=True)
    assert load_parts(obj, 1.0, "Y")[0].material["base_color_factor"] == [1.0, 1.0, 1.0, 1.0]  # the map alone
    plain = _box(tmp_path / "plain.obj", SimpleMaterial(diffuse=[204, 51, 51, 255]), texture=False)
    np.testing.assert_allclose(load_parts(plain, 1.0, "Y")[0].material["base_color_factor"][:3], [0.8, 0.2, 0.2])
