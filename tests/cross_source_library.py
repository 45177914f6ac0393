"""A library of copies another source published, and of clean objects of one shape family, for
tests/test_cross_source.py and the before/after figures in docs/curation.md.

Built from real scans pymeshlab ships (the textured Stanford bunny, the cow) and the demo builders:

* ``bunny_*``: the 10k-face textured bunny and copies decimated hard (3-4 % of the faces), flattened
  15-20 % along one axis (a re-export), stored in mm or cm, turned, re-baked (one 10 % darker); one
  re-materialed (hue turned: a colour variant from another source);
* ``cow_*``: a plain yellow cow, its decimated, flattened, turned copy in cm (same plain colour), an
  olive copy decimated and flattened (another material), and a red copy turned and stored in mm (another
  material, the shape untouched);
* clean objects, pairwise different, several of each shape family: balls, bottles, mugs, cans, cups,
  blocks, dice, figurines, cookies, donuts, fruit; and two more real scans in plain colours whose three
  principal moments differ (the airplane, mirror-asymmetric along two axes like the cow; the bone,
  mirror-symmetric), the shapes the plain-recolour rule looks at.

:data:`COPIES` holds the groups of one object; every other pair is two different objects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from mixcount.demo import library as L
from mixcount.demo import objects as O
from mixcount.demo import traps as T

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"
COPIES = (
    ("bunny", "bunny_dec_flat_mm", "bunny_dec_flat_cm_dark", "bunny_dec_flat_recoloured"),
    ("cow_yellow", "cow_yellow_dec_flat_cm", "cow_olive_dec_flat", "cow_red_turned_mm"),
)
FAMILIES = (("ball", O.build_ball, 5), ("bottle", O.build_bottle, 4), ("mug", O.build_mug, 3),
            ("can", O.build_can, 4), ("cup", O.build_cup, 2), ("block", O.build_block, 3), ("die", O.build_die, 2),
            ("figurine", O.build_figurine, 3), ("cookie", O.build_cookie, 2), ("donut", O.build_donut, 2),
            ("fruit", O.build_fruit, 3))


def _scan(name: str) -> L.Part:
    mesh = trimesh.load(SAMPLES / name, force="mesh", process=False)
    return L.Part(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces), np.asarray(mesh.visual.uv),
                  image=mesh.visual.material.image.convert("RGB"), roughness=0.7)


def _plain(name: str, rgb: tuple[int, int, int]) -> L.Part:
    mesh = trimesh.load(SAMPLES / name, force="mesh")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    return L.Part(v, np.asarray(mesh.faces), np.zeros((len(v), 2)),
                  colors=np.tile(np.array([*rgb, 255], np.uint8), (len(v), 1)))


def _flatten(parts: list[L.Part], axis: int, factor: float) -> list[L.Part]:
    s = np.ones(3)
    s[axis] = factor
    return L.baked(parts, np.diag(s), 1.0)


def objects() -> dict[str, list[L.Part]]:
    """Folder name -> parts, deterministic."""
    turn = L.rotation_xyz
    bunny = _scan("bunny10k_textured.obj")
    yellow = _plain("cow.obj", (225, 190, 40))
    out = {
        "bunny": [bunny],
        "bunny_dec_flat_mm": T.republish(_flatten([bunny], 2, 0.82), method="decimate", target_faces=400,
                                         texture_px=256, rotation=turn((90.0, 0.0, 30.0)), scale=1000.0, seed=1),
        "bunny_dec_flat_cm_dark": T.republish(_flatten([bunny], 0, 0.85), method="decimate", target_faces=300,
                                              texture_px=128, gain=0.9, rotation=turn((0.0, 0.0, 70.0)),
                                              scale=100.0, seed=2),
        "bunny_dec_flat_recoloured": L.recolour(T.republish(_flatten([bunny], 1, 0.8), method="decimate",
                                                            target_faces=400, texture_px=256,
                                                            rotation=turn((20.0, 40.0, 0.0)), scale=1.0, seed=3), 0.4),
        "cow_yellow": [yellow],
        "cow_yellow_dec_flat_cm": T.republish(_flatten([yellow], 1, 0.78), method="decimate", target_faces=250,
                                              texture_px=64, rotation=turn((90.0, 0.0, 0.0)), scale=100.0, seed=5),
        "cow_olive_dec_flat": T.republish(_flatten([_plain("cow.obj", (110, 110, 40))], 2, 0.85), method="decimate",
                                          target_faces=300, texture_px=64, rotation=turn((0.0, 90.0, 0.0)),
                                          scale=1.0, seed=4),
        "cow_red_turned_mm": L.baked([_plain("cow.obj", (190, 50, 45))], turn((0.0, 30.0, 120.0)), 1000.0),
        "airplane_grey": [_plain("airplane.obj", (150, 155, 160))],
        "bone_ivory": [_plain("bone.ply", (230, 220, 190))],
    }
    for family, build, n in FAMILIES:
        for k in range(n):
            out[f"{family}{k}"] = build(k, np.random.default_rng(100 * len(family) + k)).parts
    return out


def write_library(root: Path) -> Path:
    """Every object as ``root/<folder>/model.glb`` (a plain-folder library, metres)."""
    for name, parts in objects().items():
        (root / name).mkdir(parents=True)
        (root / name / "model.glb").write_bytes(L.export_glb(parts))
    return root


def same_object(a: str, b: str) -> bool:
    return any(a in group and b in group for group in COPIES)
