"""MuJoCo XML (MJCF) beside a model: which meshes are the object, where each part sits, which are collision only.

Packages such as metaworld ship ``basketball.xml`` (the body: geoms naming meshes, with ``pos`` /
``euler`` / ``quat``) and ``basketball_dependencies.xml`` (``<compiler angle meshdir>``, ``<asset><mesh
file scale>``, ``<default>`` classes) beside the meshes. A folder's MJCF files are read together, as
MuJoCo reads a model with its includes:

* ``<compiler angle="radian|degree">`` (MuJoCo's default is degree) for ``euler``; ``<asset><mesh>``
  gives each mesh's file (matched by file name) and ``scale`` (metres per mesh unit: the units);
* a geom's attributes come from its ``<default>`` class chain (the geom's ``class``, else the enclosing
  body's ``childclass``, else ``main``), then its own;
* a geom in ``group`` 3 or above (hidden by MuJoCo's viewer: the collision geoms of metaworld,
  robosuite and MuJoCo Menagerie), or with ``rgba`` alpha 0, is collision only; its meshes are companions
  (not objects) unless a visual geom uses them too;
* a geom naming a mesh no ``<asset>`` declares (the body file copied without its dependencies) uses the
  mesh file of that name in the folder, and a warning says so (:func:`_meshes_by_name`);
* the first body holding visual mesh geoms is the object; its visual meshes are its parts, each placed
  by its body chain and geom transform (MuJoCo's world is Z-up, lengths in metres);
* each visual part's colour, as MuJoCo shows it: the geom's ``rgba`` where it differs from MuJoCo's
  default (0.5 0.5 0.5 1), which then takes precedence over its material; else its ``material``'s
  ``rgba`` (``<asset><material>``, default 1 1 1 1) unless the material names a ``texture`` (its colour is
  the texture's); else none said (MuJoCo's default grey is nobody's choice). The colour is applied to parts whose mesh carries no colour of its own
  (:mod:`mixcount.catalog.derived`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mixcount.catalog.naming import safe_text

MJCF_ROOTS = ("mujoco", "mujocoinclude")


@dataclass
class MjcfModel:
    """What a folder's MJCF files say: visual parts (file name, 4x4 placement in metres), scale, names."""

    files: list[Path]
    name: str | None
    parts: list[tuple[str, np.ndarray]] = field(default_factory=list)  # visual meshes, placed
    collision: list[str] = field(default_factory=list)  # mesh files used only by collision geoms
    colours: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)  # visual mesh file -> RGBA
    mesh_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)  # the meshes' <mesh scale>, metres per unit
    warnings: list[str] = field(default_factory=list)


def _floats(text: str | None) -> list[float] | None:
    try:
        return [float(v) for v in (text or "").split()] or None
    except ValueError:
        return None


def _quat_matrix(q: list[float]) -> np.ndarray:
    w, x, y, z = (np.asarray(q, dtype=np.float64) / (np.linalg.norm(q) or 1.0)).tolist()
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _euler_matrix(e: list[float], radians: bool) -> np.ndarray:
    """MuJoCo's default euler sequence ``xyz`` (intrinsic rotations about the moving axes)."""
    a, b, c = (v if radians else math.radians(v) for v in e[:3])
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


def _placement(attrs: dict[str, str], radians: bool) -> np.ndarray:
    m = np.eye(4)
    pos = _floats(attrs.get("pos"))
    if pos and len(pos) == 3:
        m[:3, 3] = pos
    quat, euler = _floats(attrs.get("quat")), _floats(attrs.get("euler"))
    if quat and len(quat) == 4:
        m[:3, :3] = _quat_matrix(quat)
    elif euler and len(euler) == 3:
        m[:3, :3] = _euler_matrix(euler, radians)
    return m


def _defaults(elem: ET.Element, parent: dict[str, str], out: dict[str, dict[str, str]]) -> None:
    """Every ``<default class>``'s geom attributes, inherited from the enclosing default."""
    own = dict(parent)
    geom = elem.find("geom")
    if geom is not None:
        own.update(geom.attrib)
    out[elem.get("class", "main")] = own
    for child in elem.findall("default"):
        _defaults(child, own, out)


def is_mjcf(path: Path) -> bool:
    """True for an XML file whose root element is ``<mujoco>`` or ``<mujocoinclude>``."""
    try:
        for _event, elem in ET.iterparse(path, events=("start",)):
            return elem.tag in MJCF_ROOTS
    except (ET.ParseError, OSError):
        return False
    return False


def read_mjcf(paths: list[Path], notes: list[str] | None = None) -> MjcfModel | None:
    """The object the MJCF files of one folder describe, or None when none parses or names a mesh; a file
    that does not parse is said in ``notes``."""
    roots = []
    for path in sorted(paths):
        try:
            root = ET.parse(path).getroot()
        except (ET.ParseError, OSError) as exc:
            if notes is not None:
                text = str(exc).splitlines()[0][:200] if str(exc) else ""
                reason = getattr(exc, "strerror", None) or text or type(exc).__name__
                notes.append(f"{path.name} does not parse, not used: {reason}")
            continue
        if root.tag in MJCF_ROOTS:
            roots.append((path, root))
    if not roots:
        return None
    radians = any((c.get("angle") or "").lower() == "radian" for _p, r in roots for c in r.iter("compiler"))
    meshes: dict[str, tuple[str, list[float] | None]] = {}
    classes: dict[str, dict[str, str]] = {}
    materials: dict[str, tuple[float, float, float, float]] = {}
    for _p, root in roots:
        for material in root.iter("material"):
            colour = rgba_colour(_floats(material.get("rgba")) or [1.0, 1.0, 1.0, 1.0])  # MuJoCo's default: white
            # a textured material's colour is its texture's (rgba only tints it): no colour said here
            if material.get("name") and colour is not None and not material.get("texture"):
                materials[material.get("name", "")] = colour
        for mesh in root.iter("mesh"):
            file = mesh.get("file")
            if file:
                name = mesh.get("name") or Path(file).stem
                meshes[name] = (Path(file.replace("\\", "/")).name, _floats(mesh.get("scale")))
        for top in root.findall("default"):
            _defaults(top, {}, classes)
    found_by_name = _meshes_by_name(roots, meshes, classes)
    model = MjcfModel([p for p, _r in roots], None)
    model.warnings.extend(found_by_name)
    if found_by_name and not any(c.get("angle") for _p, r in roots for c in r.iter("compiler")):
        model.warnings.append("no <compiler angle> beside it either (it was in the file that declared the meshes?): "
                              "its euler angles are read in MuJoCo's default, degrees")
    used_visual: set[str] = set()
    used_collision: set[str] = set()
    for _p, root in roots:
        for body in root.iter("body"):
            colours: dict[str, tuple[float, float, float, float]] = {}
            found = _body_parts(body, None, body.get("childclass"), classes, meshes, radians,
                                used_visual, used_collision, materials, colours)
            if found and not model.parts:
                model.parts, model.name, model.colours = found, body.get("name"), colours
    model.collision = sorted(used_collision - used_visual)
    scales = {tuple(meshes[n][1] or (1.0, 1.0, 1.0)) for n in meshes if meshes[n][0] in used_visual}
    if len(scales) == 1:
        s = next(iter(scales))
        model.mesh_scale = (s[0], s[1], s[2]) if len(s) == 3 else (s[0],) * 3  # type: ignore[assignment]
    elif len(scales) > 1:
        model.warnings.append("the MJCF scales its meshes differently: not applied (state the units in a "
                              "metadata.json beside it)")
    if not model.parts and not model.collision:
        return None
    return model


MESH_FILES = (".stl", ".obj", ".ply", ".msh", ".glb", ".gltf")  # what a <mesh file> names, as the folder holds it


def _meshes_by_name(roots: list[tuple[Path, ET.Element]], meshes: dict[str, tuple[str, list[float] | None]],
                    classes: dict[str, dict[str, str]]) -> list[str]:
    """A geom naming a mesh that no ``<asset>`` of the folder declares (its ``*_dependencies.xml`` was not
    copied, only the body file and the meshes beside it): the mesh file of that name in the description's
    folder is used (``mesh="mug"`` -> ``mug.stl``), added to ``meshes``; returns the warnings that say so.
    Without this the description was ignored and the object read in the wrong frame (on its side)."""
    folders = {p.parent for p, _r in roots}
    files = {f.stem.lower(): f for d in sorted(folders) for f in sorted(d.iterdir())
             if f.is_file() and f.suffix.lower() in MESH_FILES}
    said = []
    for path, root in roots:
        for geom in root.iter("geom"):
            cls = geom.get("class") or "main"
            name = geom.get("mesh") or {**classes.get("main", {}), **classes.get(cls, {})}.get("mesh")
            if not name or name in meshes or name.lower() not in files:
                continue
            found = files[name.lower()]
            meshes[name] = (found.name, None)
            said.append(f"{path.name} names the mesh {safe_text(name)!r}, which no <asset> beside it declares: "
                        f"{safe_text(found.name)} in its folder is used (scale 1)")
    return said


MUJOCO_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)  # a geom's rgba when nothing sets it


def rgba_colour(values: list[float] | tuple[float, ...] | None) -> tuple[float, float, float, float] | None:
    """Four finite numbers in 0..1 as an RGBA tuple; None for anything else (a library's ``nan`` or ``2``
    is no colour, and no reason to lose the object). Every description format's colours pass here (MJCF,
    URDF, SDF)."""
    if not values or len(values) != 4 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values):
        return None
    return (values[0], values[1], values[2], values[3])


def geom_colour(attrs: dict[str, str],
                materials: dict[str, tuple[float, float, float, float]]) -> tuple[float, float, float, float] | None:
    """The colour MuJoCo shows a geom in (see the module doc), or None where nothing chose one."""
    rgba = rgba_colour(_floats(attrs.get("rgba")))
    if rgba is not None and rgba != MUJOCO_DEFAULT_RGBA:
        return rgba
    return materials.get(attrs.get("material") or "")


def _body_parts(body: ET.Element, parent: np.ndarray | None, childclass: str | None,
                classes: dict[str, dict[str, str]], meshes: dict[str, tuple[str, list[float] | None]], radians: bool,
                used_visual: set[str], used_collision: set[str],
                materials: dict[str, tuple[float, float, float, float]] | None = None,
                colours: dict[str, tuple[float, float, float, float]] | None = None) -> list[tuple[str, np.ndarray]]:
    """Visual mesh geoms of ``body`` and the bodies in it, placed in ``body``'s own frame (``parent``
    None: the object's body, whose own placement in its world does not matter); collision meshes are added
    to ``used_collision``, each visual mesh's colour (:func:`geom_colour`, the first geom's) to ``colours``."""
    here = np.eye(4) if parent is None else parent @ _placement(body.attrib, radians)
    out: list[tuple[str, np.ndarray]] = []
    for geom in body.findall("geom"):
        cls = geom.get("class") or childclass or "main"
        attrs = {**classes.get("main", {}), **classes.get(cls, {}), **geom.attrib}
        mesh = attrs.get("mesh")
        if not mesh or mesh not in meshes:
            continue
        file = meshes[mesh][0]
        group = _floats(attrs.get("group")) or [0.0]
        rgba = _floats(attrs.get("rgba")) or [1.0, 1.0, 1.0, 1.0]
        if group[0] >= 3 or (len(rgba) == 4 and rgba[3] == 0):
            used_collision.add(file)
            continue
        used_visual.add(file)
        out.append((file, here @ _placement(geom.attrib, radians)))
        colour = geom_colour(attrs, materials or {})
        if colours is not None and colour is not None:
            colours.setdefault(file, colour)
    for child in body.findall("body"):
        out.extend(_body_parts(child, here, child.get("childclass") or childclass, classes, meshes, radians,
                               used_visual, used_collision, materials, colours))
    return out
