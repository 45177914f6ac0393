"""A user's own objects as they export them, built from real files of public packages (issue 56).

Person-named folders copied out of Debian's ``prusa-slicer`` (STL parts in millimetres),
``assimp-testmodels`` (STL / PLY / glTF test models), PyPI's ``metaworld`` (MuJoCo XML beside its STL
meshes, parts of one object) and ``bd_warehouse`` (nuts, washers and screws made with build123d,
exported as STEP and as STL in millimetres). :data:`EXPECTED` gives each folder's real largest side
(metres, within 2 x) and whether it is several files merged.

``bd_warehouse`` parts are made by running build123d (it needs OpenCASCADE's ``cadquery-ocp``, which
the project does not depend on): in this interpreter when it imports build123d, else in the
interpreter ``$MIXCOUNT_CAD_PYTHON`` names; the files are cached under ``~/.cache/mixcount/cad``.
Every builder returns ``(path, "")`` or ``(None, why)``: callers skip with the reason.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from tests.public_packages import deb_tree, wheel_tree


@dataclass(frozen=True)
class Expected:
    source: str  # package
    largest_m: float | None  # the real object's largest side, metres (None: test geometry with no real size)
    units: str  # the unit ingest reads it in with defaults
    basis: str  # why: format, description, size prior, default
    parts: int = 1  # model files merged into the object


PRUSA = "usr/share/PrusaSlicer/shapes"
ASSIMP = "usr/share/assimp/models"
MW = "metaworld/assets/objects"

# folder name -> (package, files to copy, relative to the package root)
FOLDERS: dict[str, tuple[str, tuple[str, ...]]] = {
    "Hex nut M3": ("prusa-slicer", (f"{PRUSA}/M3_hex_nut.stl",)),
    "Screw M3x10": ("prusa-slicer", (f"{PRUSA}/M3x10_screw.stl",)),
    "Stanford bunny": ("prusa-slicer", (f"{PRUSA}/bunny.stl",)),
    "Torus": ("prusa-slicer", (f"{PRUSA}/torus.stl",)),
    "Recycling symbol": ("prusa-slicer", (f"{PRUSA}/PLA_recycling_symbol.stl",)),
    "Spider": ("assimp-testmodels", (f"{ASSIMP}/STL/Spider_binary.stl",)),
    "Sphere with hole": ("assimp-testmodels", (f"{ASSIMP}/STL/sphereWithHole.stl",)),
    "Wuson": ("assimp-testmodels", (f"{ASSIMP}/PLY/Wuson.ply",)),
    "Textured box": ("assimp-testmodels", (f"{ASSIMP}/glTF2/BoxTextured-glTF-Binary/BoxTextured.glb",)),
    "hammer": ("metaworld", (f"{MW}/meshes/hammer/hammerhandle.stl", f"{MW}/meshes/hammer/hammerhead.stl")),
    "basketball": ("metaworld", (f"{MW}/assets/basketball.xml", f"{MW}/assets/basketball_dependencies.xml",
                                 f"{MW}/meshes/basketball/basketballinner.stl",
                                 f"{MW}/meshes/basketball/basketballouter.stl")),
    "Soccer ball": ("metaworld", (f"{MW}/assets/soccer_ball.xml", f"{MW}/assets/soccer_dependencies.xml",
                                  f"{MW}/meshes/soccer/soccer_black.stl", f"{MW}/meshes/soccer/soccer_white.stl")),
}

# what a person knows of each: real largest side (metres), the unit and its basis, parts merged
EXPECTED: dict[str, Expected] = {
    "Hex nut M3": Expected("prusa-slicer", 0.0064, "mm", "format"),
    "Screw M3x10": Expected("prusa-slicer", 0.013, "mm", "format"),
    "Stanford bunny": Expected("prusa-slicer", 0.11, "mm", "format"),  # the print the slicer offers
    "Torus": Expected("prusa-slicer", 0.029, "mm", "format"),
    "Recycling symbol": Expected("prusa-slicer", 0.03, "mm", "format"),
    "Spider": Expected("assimp-testmodels", None, "mm", "format"),  # 8 units: test geometry
    "Sphere with hole": Expected("assimp-testmodels", None, "mm", "format"),  # 3 units
    "Wuson": Expected("assimp-testmodels", None, "m", "default"),  # PLY, 3.24 units: said implausible
    "Textured box": Expected("assimp-testmodels", 1.0, "m", "format"),  # glTF: 1 m by its specification
    "hammer": Expected("metaworld", 0.3, "m", "size prior", parts=2),  # parts each centred at the origin
    "basketball": Expected("metaworld", 0.06, "m", "description", parts=2),  # metaworld's toy ball
    "Soccer ball": Expected("metaworld", 0.05, "m", "description", parts=2),
    "Hex nut M6 (STEP)": Expected("bd_warehouse", 0.0115, "m", "format"),
    "Plain washer M6 (STEP)": Expected("bd_warehouse", 0.012, "m", "format"),
    "Socket head screw M4x12 (STL)": Expected("bd_warehouse", 0.016, "mm", "format"),
    "Hex nut M8 (STEP and STL)": Expected("bd_warehouse", 0.0150, "m", "format"),  # one model, two formats
}

CAD_SCRIPT = r'''
import sys
from pathlib import Path
from build123d import export_step, export_stl
from bd_warehouse.fastener import HexNut, PlainWasher, SocketHeadCapScrew
out = Path(sys.argv[1])
parts = {
    "Hex nut M6 (STEP)": [("hexnut_m6", HexNut("M6-1", "iso4032"), ("step",))],
    "Plain washer M6 (STEP)": [("washer_m6", PlainWasher("M6", "iso7089"), ("step",))],
    "Socket head screw M4x12 (STL)": [("screw_m4x12", SocketHeadCapScrew("M4-0.7", 12, "iso4762"), ("stl",))],
    "Hex nut M8 (STEP and STL)": [("hexnut_m8", HexNut("M8-1.25", "iso4032"), ("step", "stl"))],
}
for folder, items in parts.items():
    (out / folder).mkdir(parents=True, exist_ok=True)
    for stem, shape, kinds in items:
        if "step" in kinds:
            export_step(shape, str(out / folder / (stem + ".step")))
        if "stl" in kinds:
            export_stl(shape, str(out / folder / (stem + ".stl")))
'''


def cad_dir() -> Path:
    return Path.home() / ".cache" / "mixcount" / "cad"


def bd_warehouse_folders() -> tuple[Optional[Path], str]:
    """The bd_warehouse folders (cached), made with build123d; (None, why) when it is not to be had."""
    target = cad_dir() / "bd_warehouse-0.4.0"
    if (target / ".built").exists():
        return target, ""
    python = sys.executable
    try:
        import build123d  # noqa: F401
    except ImportError:
        python = os.environ.get("MIXCOUNT_CAD_PYTHON", "")
        if not python:
            return None, ("bd_warehouse parts need build123d (pip install build123d bd_warehouse==0.4.0), not "
                          "installed here; or set MIXCOUNT_CAD_PYTHON to a Python that has them")
    shutil.rmtree(target, ignore_errors=True)
    try:
        subprocess.run([python, "-c", CAD_SCRIPT, str(target)], check=True, timeout=600, capture_output=True)
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"build123d could not make the bd_warehouse parts ({type(exc).__name__})"
    (target / ".built").touch()
    return target, ""


def build_cad_folders(root: Path, *, packages: tuple[str, ...] = ("prusa-slicer", "assimp-testmodels", "metaworld",
                                                                  "bd_warehouse")) -> tuple[Path, list[str]]:
    """Copy the folders of the given packages under ``root`` as a user would; returns (root, reasons of
    the packages that could not be had)."""
    missing: list[str] = []
    trees: dict[str, Optional[Path]] = {}
    for pkg in packages:
        if pkg == "bd_warehouse":
            tree, why = bd_warehouse_folders()
            if tree is None:
                missing.append(why)
                continue
            for folder in tree.iterdir():
                if folder.is_dir():
                    shutil.copytree(folder, root / folder.name, dirs_exist_ok=True)
            continue
        tree, why = wheel_tree("metaworld==3.1.1") if pkg == "metaworld" else deb_tree(pkg)
        if tree is None:
            missing.append(why)
        trees[pkg] = tree
    for name, (pkg, files) in FOLDERS.items():
        tree = trees.get(pkg)
        if tree is None:
            continue
        (root / name).mkdir(parents=True, exist_ok=True)
        for rel in files:
            shutil.copy2(tree / rel, root / name / Path(rel).name)
    return root, missing
