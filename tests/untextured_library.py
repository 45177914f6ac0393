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

from pathlib import Path
from typing import Optional

from public_packages import ASSIMP, ASSIMP_MODELS, METAWORLD, METAWORLD_MESHES, PRUSA, PRUSA_SHAPES, copy_models

FILES = {  # (package, folder inside it) -> {folder named by a person: file}
    (PRUSA, PRUSA_SHAPES): {
        "Hex nut": "M3_hex_nut.stl", "Screw": "M3x10_screw.stl", "PLA badge": "PLA_recycling_symbol.stl",
        "PETG badge": "PETG_recycling_symbol.stl", "Other badge": "OTHER_recycling_symbol.stl", "Bunny": "bunny.stl",
        "Torus": "torus.stl", "Cone": "cone.stl", "Pyramid": "pyramid.stl"},
    (ASSIMP, f"{ASSIMP_MODELS}/STL"): {
        "Wuson": "Wuson.stl", "Spider": "Spider_ascii.stl", "Sphere with hole": "sphereWithHole.stl"},
    (METAWORLD, METAWORLD_MESHES): {
        "Hockey puck": "puck/puck.stl", "Cup": "coffeemachine/cup.stl", "Mug": "coffeemachine/mug.stl",
        "Basketball": "basketball/basketballouter.stl", "Hammer head": "hammer/hammerhead.stl",
        "Thermos": "thermos/therm_body.stl", "Golf club head": "golf_club/club_head.stl", "Dial": "dial/dialhead.stl"},
}
MODELS: dict[str, tuple[str, str]] = {  # folder -> (package, file inside it)
    folder: (package, f"{inside}/{name}") for (package, inside), names in FILES.items() for folder, name in names.items()}


def write_library(root: Path) -> tuple[Optional[Path], str]:
    """Copy each model into ``root/<folder>/``; (None, why) when a package cannot be had."""
    return copy_models(root, {folder: (package, rel, ()) for folder, (package, rel) in MODELS.items()})
