"""The colour a description gives a mesh without its own reaches the catalog, the render and the caption
(found while checking an untuned library): metaworld ships its objects as untextured STL parts whose
colours are in the MJCF (``<material rgba>`` named by each ``<geom>``), pybullet ships URDFs whose
``<visual><material><color rgba>`` colours an OBJ without a .mtl. Ingest read neither: those objects had
no colour (appearance ``none``), were rendered in a palette colour and captioned in it.

The real files of two packages (tests/public_packages.py; skips, saying why, when a wheel cannot be had):
metaworld's basketball (two parts: an orange ball and black seams) and coffee-machine mug (white), each a
folder of its MJCF body file, its ``*_dependencies.xml`` and its STLs; pybullet's ``sphere2red.urdf``
beside ``sphere_smooth.obj`` without its .mtl (red), and its textured domino (keeps its texture). Through
the CLI (real SQLite, real bpy renders at 48 px): the derived model's materials are the description's
colours, the renders show them and the captions name them; a missing .mtl is still said.
"""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from public_packages import METAWORLD, PYBULLET, PYBULLET_DATA, package_root
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.layouts.mjcf import geom_colour
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag
from mixcount.cli import main
from mixcount.curation.renders import canonical_render_path

pytestmark = [pytest.mark.blender]
MW = "metaworld/assets/objects"
FOLDERS = {  # folder named by a person -> (package, files inside it)
    "Basketball": (METAWORLD, (f"{MW}/assets/basketball.xml", f"{MW}/assets/basketball_dependencies.xml",
                               f"{MW}/meshes/basketball/basketballinner.stl", f"{MW}/meshes/basketball/basketballouter.stl")),
    "Mug": (METAWORLD, (f"{MW}/assets/mug.xml", f"{MW}/assets/coffeemachine_dependencies.xml",
                        f"{MW}/meshes/coffeemachine/mug.stl", f"{MW}/meshes/coffeemachine/handle.stl")),
    "Ball": (PYBULLET, (f"{PYBULLET_DATA}/sphere2red.urdf", f"{PYBULLET_DATA}/sphere_smooth.obj")),
    "Domino": (PYBULLET, tuple(f"{PYBULLET_DATA}/domino/{n}" for n in ("domino.urdf", "domino.obj", "domino.mtl", "domino.jpg"))),
}
SAID = {  # the description's colour of each visual mesh (RGB)
    "Basketball": {"basketballouter.stl": (0.7, 0.35, 0.0), "basketballinner.stl": (0.15, 0.15, 0.15)},
    "Mug": {"mug.stl": (0.85, 0.85, 0.85), "handle.stl": (0.85, 0.85, 0.85)},
    "Ball": {"sphere_smooth.obj": (1.0, 0.2, 0.2)},
}


def test_mujoco_colour_rules():
    materials = {"white": (0.85, 0.85, 0.85, 1.0)}
    assert geom_colour({"material": "white"}, materials) == (0.85, 0.85, 0.85, 1.0)
    assert geom_colour({"material": "white", "rgba": "0.5 0.5 0.5 1"}, materials) == (0.85, 0.85, 0.85, 1.0)
    assert geom_colour({"material": "white", "rgba": "1 0 0 1"}, materials) == (1.0, 0.0, 0.0, 1.0)  # rgba wins
    assert geom_colour({"rgba": "0.5 0.5 0.5 1"}, materials) is None  # MuJoCo's default: nobody's choice
    assert geom_colour({}, materials) is None


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    lib = tmp_path_factory.mktemp("described") / "lib"
    for folder, (package, files) in FOLDERS.items():
        root, why = package_root(package)
        if root is None:
            pytest.skip(why)
        (lib / folder).mkdir(parents=True)
        for rel in files:
            shutil.copy(root / rel, lib / folder / Path(rel).name)
    return lib


def test_description_colours_reach_the_model_the_render_and_the_caption(library: Path, tmp_path: Path, capsys):
    db = str(tmp_path / "catalog.db")
    base = ["--db", db, "--config", "configs/quick.toml", "--set", "canonical_render.resolution=48",
            "--set", "canonical_render.samples=2"]
    for step in (["catalog", "ingest", str(library)], ["catalog", "render"], ["catalog", "caption", "--captioner", "stub"]):
        assert main(base + step) == 0, step
    capsys.readouterr()
    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            objects = {o.name: o for o in s.scalars(select(CatalogObject))}
            meta = {n: json.loads(o.metadata_json or "{}") for n, o in objects.items()}
            renders = {n: canonical_render_path(s, o.id) for n, o in objects.items()}
            short = {o.name: c.short for o in objects.values() for c in s.scalars(
                select(CaptionSet).where(CaptionSet.object_id == o.id, CaptionSet.active.is_(True)))}
            flags = {(objects_by_id.name, f.kind) for f in s.scalars(select(Flag))
                     for objects_by_id in [s.get(CatalogObject, f.object_id)]}
    finally:
        catalog.close()
    assert set(objects) == set(FOLDERS)
    for name, said in SAID.items():
        assert meta[name]["ingest"]["appearance"] == "material", (name, meta[name]["ingest"])
        recorded = meta[name]["metadata"]["description"]["colours"]
        assert {k: tuple(v[:3]) for k, v in recorded.items()} == said
        scene = trimesh.load(objects[name].model_path, force="scene")  # the derived GLB
        got = sorted(tuple(np.round(np.asarray(g.visual.material.baseColorFactor[:3]) / 255.0, 2))
                     for g in scene.geometry.values())
        assert got == sorted(tuple(round(v, 2) for v in c) for c in said.values()), (name, got)
    assert meta["Domino"]["ingest"]["appearance"] == "image"  # its own texture, not the URDF's white
    assert objects["Domino"].model_path.endswith("domino.obj")
    assert ("Ball", "missing_material") in flags  # the .mtl sphere_smooth.obj names is still said missing

    def object_rgb(path: Path | None) -> np.ndarray:
        assert path is not None
        rgba = np.asarray(Image.open(io.BytesIO(Path(path).read_bytes())).convert("RGBA"), float) / 255
        return rgba[rgba[..., 3] > 0.5][:, :3].mean(axis=0)

    red, orange, white = object_rgb(renders["Ball"]), object_rgb(renders["Basketball"]), object_rgb(renders["Mug"])
    print(f"\nrender means: ball {red.round(2)}, basketball {orange.round(2)}, mug {white.round(2)}; captions {short}")
    assert red[0] > 1.5 * red[1] and red[0] > 1.5 * red[2]
    assert orange[0] > orange[1] > 1.5 * orange[2]
    assert white.min() > 0.5 and white.max() - white.min() < 0.1
    assert "red" in short["Ball"] and "white" in short["Mug"], short
