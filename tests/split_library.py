"""A library of real captures with repeated categories, for the split modes (issue 59).

pybullet's ``pybullet_data`` and genesis-world's ``genesis/assets`` (read out of their wheels with
:func:`tests.public_packages.wheel_tree`) copied into person-named folders, one model a folder with the
``.mtl`` and textures it names, as a user who collects package models would keep them; beside them a part
of the person-named library of :mod:`tests.named_library` (broad categories in ``metadata.json``, recolour
pairs). Kinds repeat on purpose: ducks, bunnies and mugs from both packages, three trays, six tower rings,
spheres and balls, two wheels, two dragons, two bowls, ketchup / soup / sauce recolours.

:data:`PUBLIC` names each folder after what a person would call the model; :func:`build_split_library`
writes the whole tree and returns (root, why): root None and why the reason when a wheel cannot be had.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from named_library import build_named_library
from public_packages import wheel_tree

PYBULLET = "pybullet"
GENESIS = "genesis-world"

# folder name (a person's) -> (package, path inside the unpacked wheel)
PUBLIC: dict[str, tuple[str, str]] = {
    "Rubber duck": (PYBULLET, "pybullet_data/duck.obj"),
    "Stanford bunny": (PYBULLET, "pybullet_data/bunny.obj"),
    "Coffee mug": (PYBULLET, "pybullet_data/objects/mug.obj"),
    "Mug": (PYBULLET, "pybullet_data/urdf/mug.obj"),
    "Soccer ball": (PYBULLET, "pybullet_data/soccerball.obj"),
    "Smooth sphere": (PYBULLET, "pybullet_data/sphere_smooth.obj"),
    "Textured sphere": (PYBULLET, "pybullet_data/textured_sphere_smooth.obj"),
    "Serving tray": (PYBULLET, "pybullet_data/tray/tray_textured.obj"),
    "Serving tray 2": (PYBULLET, "pybullet_data/tray/tray_textured2.obj"),
    "Trays 4": (PYBULLET, "pybullet_data/tray/tray_textured4.obj"),
    "Jenga block": (PYBULLET, "pybullet_data/jenga/jenga.obj"),
    "Lego brick": (PYBULLET, "pybullet_data/lego/lego.obj"),
    "Domino": (PYBULLET, "pybullet_data/domino/domino.obj"),
    "Torus": (PYBULLET, "pybullet_data/torus/torus_textured.obj"),
    "Toy cube": (PYBULLET, "pybullet_data/toys/cube.obj"),
    "Toy cylinder": (PYBULLET, "pybullet_data/toys/cylinder.obj"),
    "Duck": (GENESIS, "genesis/assets/meshes/duck.obj"),
    "Yellow duck": (GENESIS, "genesis/assets/meshes/duck/duck.obj"),
    "Bunny": (GENESIS, "genesis/assets/meshes/bunny.obj"),
    "Dragon": (GENESIS, "genesis/assets/meshes/dragon.obj"),
    "Stanford dragon": (GENESIS, "genesis/assets/meshes/dragon/dragon.obj"),
    "Sphere": (GENESIS, "genesis/assets/meshes/sphere.obj"),
    "Wooden sphere": (GENESIS, "genesis/assets/meshes/wooden_sphere_OBJ/wooden_sphere.obj"),
    "Ball": (GENESIS, "genesis/assets/tower/ball.glb"),
    **{f"Tower ring {k}": (GENESIS, f"genesis/assets/tower/ring_0{k}.glb") for k in range(1, 7)},
    "Wheel": (GENESIS, "genesis/assets/urdf/wheel/wheel.obj"),
    "Fancy wheel": (GENESIS, "genesis/assets/urdf/wheel/fancy_wheel.obj"),
    "Bolt": (GENESIS, "genesis/assets/meshes/bolt_nut/bolt.stl"),
    "Nut": (GENESIS, "genesis/assets/meshes/bolt_nut/nut.stl"),
    "Toy boat": (GENESIS, "genesis/assets/meshes/boat/boat.obj"),
    "Toy airplane": (GENESIS, "genesis/assets/meshes/Airplane/airplane.obj"),
    "Chopping board": (GENESIS, "genesis/assets/meshes/chopping-board/source/chopping_board.glb"),
}

# part of tests/named_library.py: recolour pairs, repeated kinds (bowls, bottles, markers, balls), broad categories
NAMED = {"red_coffee_mug", "dtc_mug_navy", "ketchup_bottle", "ketchup_bottle_blue", "alphabet_soup",
         "alphabet_soup_red", "hot_sauce", "hot_sauce_dark", "black_bowl", "white_bowl", "dtc_bowl_green", "bowl_2",
         "dtc_marker_peach", "dtc_marker_teal", "basketball", "dtc_volleyball", "soccer_ball", "banana", "apple",
         "teddy_hull", "toy_car", "block_cube", "block_plank", "wine_glass"}

_REF = re.compile(r"^\s*(?:mtllib|map_\w+|bump|norm|disp)\s+(?:-\S+\s+\S+\s+)*(.+?)\s*$", re.IGNORECASE)


def _referenced(path: Path) -> list[str]:
    """Relative files an OBJ names (its .mtl) or a .mtl names (its textures)."""
    if path.suffix.lower() not in (".obj", ".mtl"):
        return []
    out = []
    for line in path.read_text(errors="replace").splitlines():
        m = _REF.match(line)
        if m and not Path(m.group(1)).is_absolute():
            out.append(m.group(1).replace("\\", "/"))
    return out


def _copy_with_companions(src: Path, folder: Path) -> None:
    """``src`` into ``folder`` with every file it names, recursively, at the same relative paths."""
    todo, seen = [src], set()
    while todo:
        f = todo.pop()
        if f in seen or not f.is_file():
            continue
        seen.add(f)
        target = folder / f.relative_to(src.parent) if f.is_relative_to(src.parent) else folder / f.name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(f, target)
        todo += [(f.parent / ref).resolve() for ref in _referenced(f)]


# the five models over 10,000 faces (the genesis bunny, dragons and duck, the bolt): most of `catalog filter`'s
# time on this library; the suite's test leaves them out (``light=True``)
HEAVY = {"Bunny", "Dragon", "Stanford dragon", "Yellow duck", "Bolt"}


def build_split_library(root: Path, *, light: bool = False) -> tuple[Path | None, str]:
    """The library under ``root`` (``root/public/<folder>/`` and ``root/named/<slug>/``), without
    :data:`HEAVY` when ``light``; (None, why) when a wheel cannot be had."""
    trees = {}
    for dist in (PYBULLET, GENESIS):
        tree, why = wheel_tree(dist)
        if tree is None:
            return None, why
        trees[dist] = tree
    for folder, (dist, rel) in PUBLIC.items():
        if light and folder in HEAVY:
            continue
        src = trees[dist] / rel
        if not src.is_file():
            return None, f"{dist} wheel has no {rel}"
        _copy_with_companions(src, root / "public" / folder)
    build_named_library(root / "named", only=NAMED)
    return root, ""
