"""An untextured library as a new user would make one (issue 57): 20 real models from three public packages,
each in a folder named by a person, no texture, no colour.

* Debian ``prusa-slicer`` (``usr/share/PrusaSlicer/shapes``): a hex nut, a screw, three recycling badges,
  a bunny, a torus, a cone, a pyramid;
* Debian ``assimp-testmodels``: the Wuson figure, a spider, a sphere with a hole;
* PyPI ``metaworld`` (``metaworld/assets/objects/meshes``): a hockey puck, a cup, a mug, a basketball, a
  hammer head, a thermos body, a golf-club head, a dial.

Every pair is two different objects (the three badges differ by their embossed letters): curation must
exclude none of them on appearance, and raise at most a few pairs for a person.
:func:`write_library` returns (root, "") or (None, why) when a package cannot be had."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Optional

from public_packages import deb_tree, wheel_tree

PRUSA = "usr/share/PrusaSlicer/shapes"
ASSIMP = "usr/share/assimp/models"
META = "metaworld/assets/objects/meshes"
METAWORLD = "metaworld==3.1.1"

MODELS: dict[str, tuple[str, str]] = {  # folder -> (package, file inside it)
    "Hex nut": ("prusa-slicer", f"{PRUSA}/M3_hex_nut.stl"),
    "Screw": ("prusa-slicer", f"{PRUSA}/M3x10_screw.stl"),
    "PLA badge": ("prusa-slicer", f"{PRUSA}/PLA_recycling_symbol.stl"),
    "PETG badge": ("prusa-slicer", f"{PRUSA}/PETG_recycling_symbol.stl"),
    "Other badge": ("prusa-slicer", f"{PRUSA}/OTHER_recycling_symbol.stl"),
    "Bunny": ("prusa-slicer", f"{PRUSA}/bunny.stl"),
    "Torus": ("prusa-slicer", f"{PRUSA}/torus.stl"),
    "Cone": ("prusa-slicer", f"{PRUSA}/cone.stl"),
    "Pyramid": ("prusa-slicer", f"{PRUSA}/pyramid.stl"),
    "Wuson": ("assimp-testmodels", f"{ASSIMP}/STL/Wuson.stl"),
    "Spider": ("assimp-testmodels", f"{ASSIMP}/STL/Spider_ascii.stl"),
    "Sphere with hole": ("assimp-testmodels", f"{ASSIMP}/STL/sphereWithHole.stl"),
    "Hockey puck": (METAWORLD, f"{META}/puck/puck.stl"),
    "Cup": (METAWORLD, f"{META}/coffeemachine/cup.stl"),
    "Mug": (METAWORLD, f"{META}/coffeemachine/mug.stl"),
    "Basketball": (METAWORLD, f"{META}/basketball/basketballouter.stl"),
    "Hammer head": (METAWORLD, f"{META}/hammer/hammerhead.stl"),
    "Thermos": (METAWORLD, f"{META}/thermos/therm_body.stl"),
    "Golf club head": (METAWORLD, f"{META}/golf_club/club_head.stl"),
    "Dial": (METAWORLD, f"{META}/dial/dialhead.stl"),
}


def package_root(package: str) -> tuple[Optional[Path], str]:
    """The unpacked package (a Debian package name, or a pip requirement with ``==``)."""
    return wheel_tree(package) if "==" in package else deb_tree(package)


def write_library(root: Path) -> tuple[Optional[Path], str]:
    """Copy each model into ``root/<folder>/``; (None, why) when a package cannot be had."""
    roots: dict[str, Path] = {}
    for package, _ in MODELS.values():
        if package not in roots:
            got, why = package_root(package)
            if got is None:
                return None, why
            roots[package] = got
    for folder, (package, rel) in MODELS.items():
        source = roots[package] / rel
        if not source.is_file():
            return None, f"{package} holds no {rel}"
        (root / folder).mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, root / folder / source.name)
    return root, ""
