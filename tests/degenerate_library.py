"""A capture-like library whose meshes carry degenerate or invalid triangles, for tests/test_stage_import.py
(issue 60: Blender's USD importer segfaulted on composed stages whose assets held such faces).

Two halves:

* ``welded_*`` (built here): the real scans pymeshlab ships (the textured Stanford bunny, the cow, the
  airplane, the bone) as a scanner's export would have them, as GLB, with ``WELDS`` triangles whose
  two corners were welded into one index (a repeated vertex: what Blender calls "invalid face data")
  and ``SLIVERS`` whose corner was moved onto another (distinct indices, zero area); one clean copy of
  each scan as a control.
* ``public_*``: real files of public packages that carry such faces themselves (found by a survey of
  1,717 models of the cached wheels and Debian packages; none of them was looked at when the rule in
  mixcount/usd/mesh_clean.py was written): assimp's test models (an OBJ of 466 repeated-vertex
  triangles, a glTF engine of 10,413), pybullet's lidar, lego brick, leg and spider, and clean ones
  (duck, bunny, soccer ball). Skipped with the reason when the packages cannot be had.

:func:`write_library` writes ``<name>/model.<ext>`` (+ ``metadata.json``, and an OBJ's MTL and textures)
and returns name -> expected bad faces of the model file (0 for controls)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"
SCANS = {"bunny": ("bunny10k_textured.obj", "figurine"), "cow": ("cow.obj", "figurine"),
         "airplane": ("airplane.obj", "toy"), "bone": ("bone.ply", "bone")}
WELDS, SLIVERS = 52, 20
# (name, package kind, package, path inside it, category, units)
PUBLIC = (
    ("public_box_longline", "deb", "assimp-testmodels", "usr/share/assimp/models/OBJ/box_longline.obj", "box", "cm"),
    ("public_engine", "deb", "assimp-testmodels",
     "usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb", "engine", "mm"),
    ("public_spider", "deb", "assimp-testmodels", "usr/share/assimp/models/OBJ/spider.obj", "spider", "cm"),
    ("public_hokuyo", "wheel", "pybullet==3.2.7", "pybullet_data/racecar/meshes/hokuyo.obj", "sensor", "m"),
    ("public_lego", "wheel", "pybullet==3.2.7", "pybullet_data/lego/lego.obj", "brick", "m"),
    ("public_calf", "wheel", "pybullet==3.2.7", "pybullet_data/aliengo/meshes/calf.obj", "leg", "m"),
    ("public_duck", "wheel", "pybullet==3.2.7", "pybullet_data/duck.obj", "duck", "cm"),
    ("public_bunny", "wheel", "pybullet==3.2.7", "pybullet_data/bunny.obj", "bunny", "dm"),
    ("public_soccerball", "wheel", "pybullet==3.2.7", "pybullet_data/soccerball.obj", "ball", "dm"),
)


def _welded(mesh: trimesh.Trimesh, rng: np.random.Generator) -> trimesh.Trimesh:
    """``mesh`` with WELDS triangles of a repeated index and SLIVERS of zero area (a corner moved onto
    another through a new vertex, so the indices stay distinct)."""
    faces = np.array(mesh.faces)
    verts = np.array(mesh.vertices)
    picks = rng.choice(len(faces), WELDS + SLIVERS, replace=False)
    for i in picks[:WELDS]:
        faces[i, 2] = faces[i, 0]
    extra = []
    for i in picks[WELDS:]:
        extra.append(verts[faces[i, 0]])
        faces[i, 2] = len(verts) + len(extra) - 1
    visual = mesh.visual
    uv = getattr(visual, "uv", None)
    out = trimesh.Trimesh(np.vstack([verts, extra]), faces, process=False)
    if uv is not None and getattr(visual, "material", None) is not None:
        uv2 = np.vstack([uv, uv[[faces[i, 0] for i in picks[WELDS:]]]])
        out.visual = trimesh.visual.TextureVisuals(uv=uv2, material=visual.material)
    return out


def _scan(name: str) -> trimesh.Trimesh:
    mesh = trimesh.load(str(SAMPLES / SCANS[name][0]), force="mesh", process=False)
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(0.12 / float(mesh.extents.max()))  # a hand-sized object, in metres
    return mesh


def _copy_obj(src: Path, target: Path) -> None:
    """An OBJ with its MTL files and the textures they name."""
    shutil.copyfile(src, target / "model.obj")
    for line in src.read_text(errors="replace").splitlines():
        if line.startswith("mtllib"):
            mtl = src.parent / line.split(None, 1)[1].strip()
            if mtl.is_file():
                shutil.copyfile(mtl, target / mtl.name)
                for m in re.finditer(r"^\s*map_\w+\s+(?:-\S+\s+\S+\s+)*(\S+)\s*$", mtl.read_text(errors="replace"), re.M):
                    tex = src.parent / m.group(1)
                    if tex.is_file():
                        shutil.copyfile(tex, target / tex.name)


def _bad_faces(model: Path) -> int:
    from mixcount.usd.mesh_clean import bad_triangles

    scene = trimesh.load(str(model), force="scene", process=False)
    return sum(int(sum(m.sum() for m in bad_triangles(g.vertices, g.faces).values()))
               for g in scene.geometry.values() if len(getattr(g, "faces", ())))


def write_library(root: Path, only: Optional[tuple[str, ...]] = None) -> tuple[dict[str, int], Optional[str]]:
    """The library under ``root`` (module docstring; ``only``: these public entries alone): name -> bad
    faces its model file holds (counted by mixcount/usd/mesh_clean.py's rule), and why the public half
    is missing (None when it is there)."""
    from public_packages import deb_tree, wheel_tree

    rng = np.random.default_rng(60)
    expected: dict[str, int] = {}
    for name, (_file, category) in SCANS.items():
        for kind in ("welded", "clean"):
            mesh = _scan(name)
            if kind == "welded":
                mesh = _welded(mesh, rng)
            target = root / f"{kind}_{name}"
            target.mkdir(parents=True, exist_ok=True)
            mesh.export(target / "model.glb")
            (target / "metadata.json").write_text(json.dumps({"name": f"{kind} {name}", "category": category,
                                                              "units": "m", "up_axis": "Z"}))
            expected[target.name] = _bad_faces(target / "model.glb")
    why = None
    for name, kind, package, inner, category, units in PUBLIC:
        if only is not None and name not in only:
            continue
        tree, reason = deb_tree(package) if kind == "deb" else wheel_tree(package)
        if tree is None:
            why = reason
            continue
        src = tree / inner
        target = root / name
        target.mkdir(parents=True, exist_ok=True)
        if src.suffix == ".obj":
            _copy_obj(src, target)
        else:
            shutil.copyfile(src, target / f"model{src.suffix}")
        (target / "metadata.json").write_text(json.dumps({"name": name.replace("_", " "), "category": category,
                                                          "units": units}))
        expected[name] = _bad_faces(src)
    return expected, why
