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
from mixcount.config import load_config
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
    "Sphere": (PYBULLET, (f"{PYBULLET_DATA}/sphere_smooth.obj",)),  # no description, its .mtl missing
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
    # what a library may write instead of a colour is none: not a crash, not a broken object
    assert geom_colour({"rgba": "nan 0 0 1"}, {}) is None and geom_colour({"rgba": "2 0 0 1"}, {}) is None
    assert geom_colour({"rgba": "1 0 0"}, {}) is None and geom_colour({"rgba": "red"}, {}) is None


def test_a_description_colour_that_is_no_colour_is_ignored(tmp_path: Path, capsys):
    """A URDF and an MJCF whose colours are ``nan`` or out of range: the object ingests as if no colour
    were given (not broken, its own look), through the CLI."""
    from mixcount.catalog.layouts.companions import read_description

    lib = tmp_path / "lib"
    for folder, rgba in (("Bad urdf", "nan 0 0 1"), ("Far urdf", "3 0 0 1")):
        (lib / folder).mkdir(parents=True)
        trimesh.creation.box((0.05, 0.05, 0.05)).export(lib / folder / "box.stl")
        (lib / folder / "box.urdf").write_text(
            f'<robot name="b"><link name="l"><visual><geometry><mesh filename="box.stl"/></geometry>'
            f'<material name="m"><color rgba="{rgba}"/></material></visual></link></robot>')
        desc = read_description(lib / folder / "box.urdf")
        assert desc is not None and desc.colours == {}, desc
    (lib / "Bad mjcf").mkdir()
    trimesh.creation.box((0.05, 0.05, 0.05)).export(lib / "Bad mjcf" / "box.stl")
    (lib / "Bad mjcf" / "box.xml").write_text(
        '<mujoco><asset><mesh file="box.stl"/><material name="m" rgba="nan 1 1 1"/></asset>'
        '<worldbody><body name="box"><geom mesh="box" material="m" rgba="5 5 5 1"/></body></worldbody></mujoco>')
    db = str(tmp_path / "catalog.db")
    assert main(["--db", db, "--config", "configs/quick.toml", "catalog", "ingest", str(lib)]) == 0
    capsys.readouterr()
    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            objects = list(s.scalars(select(CatalogObject)))
            assert len(objects) == 3 and all(o.status == "active" for o in objects), [(o.name, o.status) for o in objects]
            assert all(json.loads(o.metadata_json)["ingest"]["appearance"] == "none" for o in objects)
            assert all(o.model_path.endswith(".stl") for o in objects)  # nothing derived for no colour
    finally:
        catalog.close()


@pytest.fixture(scope="module")
def catalog_db(tmp_path_factory) -> str:
    """The folders above ingested, rendered (48 px) and captioned (stub) through the CLI."""
    root_dir = tmp_path_factory.mktemp("described")
    lib = root_dir / "lib"
    for folder, (package, files) in FOLDERS.items():
        root, why = package_root(package)
        if root is None:
            pytest.skip(why)
        (lib / folder).mkdir(parents=True)
        for rel in files:
            shutil.copy(root / rel, lib / folder / Path(rel).name)
    db = str(root_dir / "catalog.db")
    base = ["--db", db, "--config", "configs/quick.toml", "--set", "canonical_render.resolution=48",
            "--set", "canonical_render.samples=2"]
    for step in (["catalog", "ingest", str(lib)], ["catalog", "render"], ["catalog", "caption", "--captioner", "stub"]):
        assert main(base + step) == 0, step
    return db


def _object_rgb(path: Path | None) -> np.ndarray:
    """Mean colour of a canonical render's object pixels (alpha > 0.5)."""
    assert path is not None
    rgba = np.asarray(Image.open(io.BytesIO(Path(path).read_bytes())).convert("RGBA"), float) / 255
    return rgba[rgba[..., 3] > 0.5][:, :3].mean(axis=0)


def test_description_colours_reach_the_model_the_render_and_the_caption(catalog_db: str):
    db = catalog_db
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

    red, orange, white = _object_rgb(renders["Ball"]), _object_rgb(renders["Basketball"]), _object_rgb(renders["Mug"])
    print(f"\nrender means: ball {red.round(2)}, basketball {orange.round(2)}, mug {white.round(2)}; captions {short}")
    assert red[0] > 1.5 * red[1] and red[0] > 1.5 * red[2]
    assert orange[0] > orange[1] > 1.5 * orange[2]
    assert white.min() > 0.5 and white.max() - white.min() < 0.1
    assert "red" in short["Ball"] and "white" in short["Mug"], short


def test_an_obj_without_its_mtl_looks_the_same_in_the_render_the_scene_asset_and_the_caption(catalog_db: str):
    """pybullet's ``sphere_smooth.obj`` names a ``.mtl`` that is not shipped and has texture coordinates:
    trimesh gives it a stand-in 2x2 grey image and Blender's OBJ importer a default material named after
    its ``usemtl``. Ingest read the stand-in as a texture (appearance ``image``), the canonical render kept
    Blender's near-white default and the caption said the stand-in's grey. Now it has no colour of its own
    (appearance ``none``): the palette look is its colour in the canonical render, in the USD asset scenes
    are built from and in the caption alike, and the missing .mtl is still said."""
    from mixcount.captions.colours import family, name_rgb
    from mixcount.catalog.materials import object_look
    from mixcount.usd.model_parts import load_parts

    catalog = open_catalog(catalog_db, data_dir="")
    try:
        with catalog.session() as s:
            obj = s.scalars(select(CatalogObject).where(CatalogObject.name == "Sphere")).one()
            render = canonical_render_path(s, obj.id)
            caption = s.scalars(select(CaptionSet).where(CaptionSet.object_id == obj.id, CaptionSet.active.is_(True))).one()
            kinds = {f.kind for f in s.scalars(select(Flag).where(Flag.object_id == obj.id))}
            meta = json.loads(obj.metadata_json or "{}")
            look = object_look(load_config().palette, name=obj.name, category=obj.category or "",
                               metadata_json=obj.metadata_json, content_hash=obj.content_hash or "")
            model_path = obj.model_path
    finally:
        catalog.close()
    assert meta["ingest"]["appearance"] == "none" and "missing_material" in kinds
    assert look is not None
    rendered = _object_rgb(render)
    colour = family(name_rgb(look.rgb8())) or name_rgb(look.rgb8())
    seen = family(name_rgb(tuple(int(round(255 * v)) for v in rendered))) or name_rgb(tuple(int(round(255 * v)) for v in rendered))
    print(f"\nlook {look.rgb8()} ({colour}), render mean {rendered.round(2)} ({seen}); caption {caption.short!r}")
    assert seen == colour, (seen, colour)
    assert colour in caption.short or name_rgb(look.rgb8()) in caption.short, caption.short
    parts = load_parts(Path(model_path), 1.0, "Y", look.as_tuple())
    assert parts and all(p.material is not None and p.material.get("base_color_tex") is None for p in parts)
