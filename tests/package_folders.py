"""A user's model folders, built from files shaped like what packages ship (pybullet's ``pybullet_data``).

One folder per object, named by a person (``Rubber duck/``, ``red_mug/``, ``blue_mug/``), each holding
what the package puts beside the model: a ``.mtl`` (or none: ``cube.obj`` names a ``cube.mtl`` that is not
there), textures (one missing, one at ``../cube.png`` that is copied beside the model, one at a Windows
path), a URDF (Z-up bodies; one mounts a Y-up mesh with ``rpy="1.5707963 0 0"``; scales like ``.05``),
collision companions (``mug_col.obj``, ``duck_vhacd.obj``, ``l_finger_collision.stl``) and a level of
detail (``chair_lod1.obj``). :data:`EXPECTED` is what ingest must make of each folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image


@dataclass(frozen=True)
class Expected:
    category: str
    dims: tuple[float, float, float]  # metres, Z-up: the last is the height of the upright object
    up_axis: str
    warnings: tuple[str, ...] = ()  # flag kinds ingest writes
    collision_companion: bool = False


EXPECTED: dict[str, Expected] = {
    "Rubber duck": Expected("duck", (0.05, 0.04, 0.06), "Z", collision_companion=True),
    "Serving tray": Expected("tray", (0.4, 0.3, 0.03), "Z"),
    "Sugar cube": Expected("cube", (0.02, 0.02, 0.02), "Z", ("missing_material",)),
    "Jenga block": Expected("block", (0.075, 0.025, 0.015), "Z", ("missing_texture",)),
    "Dice": Expected("dice", (0.016, 0.016, 0.016), "Z", ("ingest_note",)),
    "red_mug": Expected("mug", (0.08, 0.08, 0.1), "Z", ("ingest_note",), collision_companion=True),
    "blue_mug": Expected("mug", (0.08, 0.08, 0.1), "Z", ("ingest_note",), collision_companion=True),
    "Teddy bear": Expected("bear", (0.2, 0.1, 0.4), "Y", collision_companion=True),
    "Gripper finger": Expected("finger", (0.01, 0.02, 0.06), "Z", collision_companion=True),
    "Kitchen chair": Expected("chair", (0.45, 0.5, 0.9), "Z"),
    "Soccer ball": Expected("ball", (0.22, 0.22, 0.22), "Z"),
}
COMPANION_FILES = ("duck_vhacd.obj", "mug_col.obj", "teddy2_VHACD_CHs.obj", "l_finger_collision.stl", "chair_lod1.obj")


def _obj_text(mesh: trimesh.Trimesh, mtl: str | None, material: str = "m") -> str:
    body = mesh.export(file_type="obj", include_normals=False, include_texture=False)
    lines = [ln for ln in body.splitlines() if not ln.startswith(("mtllib", "usemtl"))]
    head = [f"mtllib {mtl}", f"usemtl {material}"] if mtl else []
    return "\n".join(head + lines) + "\n"


def _box(extents: tuple[float, float, float]) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents)


def _mug(radius: float, height: float) -> trimesh.Trimesh:
    """A mug standing along +Z (its opening at the top), with an offset so it sits on z = 0."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=24)
    mesh.apply_translation((0, 0, height / 2))
    return mesh


def _urdf(name: str, visual: str, scale: float = 1.0, rpy: str = "0 0 0", collision: str | None = None) -> str:
    coll = (f'<collision><origin rpy="{rpy}" xyz="0 0 0"/><geometry><mesh filename="{collision}" '
            f'scale="{scale} {scale} {scale}"/></geometry></collision>' if collision else
            '<collision><geometry><box size="1 1 1"/></geometry></collision>')
    return (f'<?xml version="1.0" ?>\n<robot name="{name}">\n  <link name="baseLink">\n'
            f'    <visual>\n      <origin rpy="{rpy}" xyz="0 0 0"/>\n      <geometry>\n'
            f'        <mesh filename="{visual}" scale="{scale} {scale} {scale}"/>\n      </geometry>\n'
            f'    </visual>\n    {coll}\n  </link>\n</robot>\n')


def _png(path: Path, colour: tuple[int, int, int]) -> None:
    Image.new("RGB", (8, 8), colour).save(path)


def build_package_folders(root: Path) -> Path:
    """Write the folders of :data:`EXPECTED` under ``root``; returns ``root``."""
    root.mkdir(parents=True, exist_ok=True)

    duck = root / "Rubber duck"  # pybullet_data/duck*: scale .05, a V-HACD companion, a texture
    duck.mkdir()
    (duck / "duck.obj").write_text(_obj_text(_box((1.0, 0.8, 1.2)), "duck.mtl"))
    (duck / "duck.mtl").write_text("newmtl m\nKd 1 1 0.4\nmap_Kd duckCM.png\n")
    _png(duck / "duckCM.png", (250, 220, 40))
    (duck / "duck_vhacd.obj").write_text(_obj_text(_box((1.02, 0.82, 1.22)), None))
    (duck / "duck_vhacd.urdf").write_text(_urdf("duck_vhacd.urdf", "duck.obj", 0.05, collision="duck_vhacd.obj"))

    tray = root / "Serving tray"  # pybullet_data/tray: the model's stem is not its name
    tray.mkdir()
    (tray / "tray_textured.obj").write_text(_obj_text(_box((0.4, 0.3, 0.03)), "tray_textured.mtl"))
    (tray / "tray_textured.mtl").write_text("newmtl m\nKd 0.8 0.8 0.8\nmap_Kd tray.jpg\n")
    Image.new("RGB", (8, 8), (120, 80, 40)).save(tray / "tray.jpg")
    (tray / "tray.urdf").write_text(_urdf("tray", "tray_textured.obj"))

    cube = root / "Sugar cube"  # pybullet_data/cube.obj names cube.mtl, which the package lacks
    cube.mkdir()
    (cube / "cube.obj").write_text(_obj_text(_box((1.0, 1.0, 1.0)), "cube.mtl"))
    (cube / "cube.urdf").write_text(_urdf("cube", "cube.obj", 0.02))

    jenga = root / "Jenga block"  # a material naming a texture that is not shipped
    jenga.mkdir()
    (jenga / "jenga.obj").write_text(_obj_text(_box((0.075, 0.025, 0.015)), "jenga.mtl"))
    (jenga / "jenga.mtl").write_text("newmtl m\nKd 0.9 0.7 0.5\nmap_Kd jenga.tga\n")
    (jenga / "jenga.urdf").write_text(_urdf("jenga", "jenga.obj"))

    dice = root / "Dice"  # ../cube.png in the package; the user copied cube.png beside the model
    dice.mkdir()
    (dice / "dice.obj").write_text(_obj_text(_box((0.016, 0.016, 0.016)), "dice.mtl"))
    (dice / "dice.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd ../cube.png\n")
    _png(dice / "cube.png", (255, 255, 255))
    (dice / "dice.urdf").write_text(_urdf("dice", "dice.obj"))

    for colour, rgb in (("red", (200, 30, 30)), ("blue", (30, 30, 200))):
        mug = root / f"{colour}_mug"  # pybullet_data/objects/mug*: both files are called mug
        mug.mkdir()
        (mug / "mug.obj").write_text(_obj_text(_mug(0.04, 0.1), "mug.mtl"))
        # a texture referenced by a Windows path (pybullet_data/table.mtl has one), shipped by name
        (mug / "mug.mtl").write_text(f"newmtl m\nKd {rgb[0] / 255} {rgb[1] / 255} {rgb[2] / 255}\n"
                                     f"map_Kd E:\\develop\\bullet3\\data\\mug\\{colour}.png\n")
        _png(mug / f"{colour}.png", rgb)
        (mug / "mug_col.obj").write_text(_obj_text(_mug(0.041, 0.1), None))
        (mug / "mug.urdf").write_text(_urdf("mug", "mug.obj", collision="mug_col.obj"))

    teddy = root / "Teddy bear"  # a Y-up mesh the URDF stands up with rpy 90 degrees about X
    teddy.mkdir()
    (teddy / "teddy2_VHACD_CHs.obj").write_text(_obj_text(_box((0.2, 0.4, 0.1)), None))
    (teddy / "teddy.obj").write_text(_obj_text(_box((0.2, 0.4, 0.1)), None))
    (teddy / "teddy_large.urdf").write_text(_urdf("teddy", "teddy.obj", rpy="1.5707963 0 0"))

    finger = root / "Gripper finger"  # STL: CAD's Z-up, no URDF
    finger.mkdir()
    _box((0.01, 0.02, 0.06)).export(finger / "l_finger.stl")
    _box((0.011, 0.021, 0.061)).export(finger / "l_finger_collision.stl")

    chair = root / "Kitchen chair"  # a level of detail beside the model, Z-up by its URDF
    chair.mkdir()
    (chair / "chair.obj").write_text(_obj_text(_box((0.45, 0.5, 0.9)), None))
    (chair / "chair_lod1.obj").write_text(_obj_text(_box((0.45, 0.5, 0.9)), None))
    (chair / "chair.urdf").write_text(_urdf("chair", "chair.obj"))

    ball = root / "Soccer ball"  # an SDF beside the model
    ball.mkdir()
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    (ball / "soccerball.obj").write_text(_obj_text(sphere, None))
    (ball / "soccerball.sdf").write_text(
        '<?xml version="1.0"?>\n<sdf version="1.6"><model name="soccerball"><link name="l"><visual name="v">'
        '<pose>0 0 0 0 0 0</pose><geometry><mesh><uri>model://soccerball/soccerball.obj</uri>'
        '<scale>0.11 0.11 0.11</scale></mesh></geometry></visual></link></model></sdf>\n')
    assert np.isfinite(sphere.vertices).all()
    return root
