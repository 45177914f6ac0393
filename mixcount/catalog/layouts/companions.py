"""What ships beside a model in real folders: companion meshes and a robot description (URDF/SDF/MJCF).

Packages such as pybullet's ``pybullet_data`` put next to ``mug.obj`` a collision mesh ``mug_col.obj``
(also ``duck_vhacd.obj``, ``l_finger_collision.stl``), levels of detail (``chair_lod1.obj``) and a
``mug.urdf`` that names the visual mesh, its scale and the orientation it is mounted with. Such a folder
is one object: the companions are not objects of their own (a collision companion becomes the object's
physics source, :func:`mixcount.catalog.mesh.analyse_model`), and the description says which mesh is the
model, its scale (units) and its up axis (URDF and SDF bodies are Z-up: a visual turned by ``rpy``
tells which axis of the mesh points up). MuJoCo XML (MJCF, :mod:`.mjcf`) is read the same way, and
also says where each visual part of a multi-part object sits and which meshes are collision only.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mixcount.catalog.layouts.mjcf import is_mjcf, read_mjcf, rgba_colour
from mixcount.catalog.naming import safe_text
from mixcount.library_root import reference_refusal

# collision companions: mug_col, duck_vhacd, teddy2_VHACD_CHs, l_finger_collision, cube_collisionfilter
_COLLISION = re.compile(r"[_\-\s.](col|coll|collider|collision\w*|vhacd\w*|convex|hull|phys|physics)$"
                        r"|vhacd|collision", re.IGNORECASE)
# levels of detail other than the first: chair_lod1, chair_LOD2, chair-lod_3 (lod0 is the model itself)
_LOD = re.compile(r"[_\-\s.]lod[_\-]?([1-9]\d*)$", re.IGNORECASE)
DESCRIPTION_EXTENSIONS = (".urdf", ".sdf")


def companion_kind(stem: str) -> str | None:
    """``collision`` or ``lod`` when a file stem names a companion of another model, else None."""
    if _COLLISION.search(stem):
        return "collision"
    if _LOD.search(stem):
        return "lod"
    return None


def companion_base(stem: str) -> str:
    """The model stem a companion belongs to: ``mug_col`` -> ``mug``, ``duck_vhacd`` -> ``duck``."""
    base = re.sub(r"[_\-\s.]?(col|coll|collider|collision\w*|vhacd\w*|convex|hull|phys|physics)$", "", stem,
                  flags=re.IGNORECASE)
    return _LOD.sub("", base)


@dataclass
class RobotDescription:
    """What a URDF/SDF beside a model says about it."""

    path: Path
    name: str | None
    visual: str | None  # mesh file name of the first visual, as written
    collision: str | None  # mesh file name of the first collision mesh
    mesh_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    up_axis: str | None = None  # the mesh axis the description turns to +Z (X, Y or Z), None if none is
    warnings: list[str] = field(default_factory=list)
    # MJCF: every visual part (file name, 4x4 placement in metres) and every collision-only mesh file
    parts: list[tuple[str, np.ndarray]] = field(default_factory=list)
    collision_files: tuple[str, ...] = ()
    kind: str = ""  # URDF, SDF or MJCF
    # the colour the description gives each visual mesh (file name -> RGBA 0..1): applied where the mesh
    # carries none of its own (:mod:`mixcount.catalog.derived`)
    colours: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)

    def units(self) -> str | None:
        """The units the scale amounts to (metres per mesh unit, as :func:`mixcount.frame.unit_scale`
        reads it): ``m`` for 1, else the factor; None for an uneven or unusable scale (a model has one
        scale in the catalog: an uneven one is reported, not applied)."""
        lo, hi = min(self.mesh_scale), max(self.mesh_scale)
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo <= 0 or hi - lo > 1e-9 * hi:
            return None
        return "m" if abs(hi - 1.0) < 1e-9 else f"{hi:g}"


def _floats(text: str | None, n: int) -> tuple[float, ...] | None:
    try:
        values = tuple(float(v) for v in (text or "").split())
    except ValueError:
        return None
    return values if len(values) == n else None


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def up_axis_of_rpy(rpy: tuple[float, ...]) -> str | None:
    """The mesh axis (X, Y, Z) a URDF/SDF visual rotation turns to the body's +Z, or None when it is a
    negative or a slanted axis (the frame rule has only X, Y and Z)."""
    world_z_in_mesh = _rpy_matrix(*rpy).T @ np.array([0.0, 0.0, 1.0])
    k = int(np.argmax(np.abs(world_z_in_mesh)))
    if world_z_in_mesh[k] < 0.99:
        return None
    return "XYZ"[k]


def _mesh_of(elem: ET.Element | None, sdf: bool) -> tuple[str | None, str | None, str | None]:
    """(file name, scale text, rpy text) of the first mesh under a visual/collision element."""
    if elem is None:
        return None, None, None
    mesh = elem.find(".//mesh")
    if mesh is None:
        return None, None, None
    if sdf:
        uri = mesh.findtext("uri")
        scale = mesh.findtext("scale")
        pose = _floats(elem.findtext("pose"), 6)
        rpy = " ".join(str(v) for v in pose[3:]) if pose else None
    else:
        uri = mesh.get("filename")
        scale = mesh.get("scale")
        origin = elem.find("origin")
        rpy = origin.get("rpy") if origin is not None else None
    return uri, scale, rpy


def _rgba(text: str | None) -> tuple[float, float, float, float] | None:
    """RGBA 0..1 from ``r g b a`` (or ``r g b``: opaque) text (:func:`~.mjcf.rgba_colour`)."""
    three = _floats(text, 3)
    return rgba_colour(_floats(text, 4) or ((*three, 1.0) if three else None))


def visual_colour(root: ET.Element, visual: ET.Element | None, sdf: bool) -> tuple[float, float, float, float] | None:
    """The colour a URDF or SDF visual gives its mesh, or None where it gives none.

    URDF (ROS ``urdf`` / pybullet): the visual's ``<material>``, its own ``<color rgba>`` or, by name, a
    ``<material>`` of the robot that has one. SDF: the visual's ``<material><diffuse>`` (else ``<ambient>``);
    a Gazebo script material (``<script>``) names no colour here."""
    material = visual.find("material") if visual is not None else None
    if material is None:
        return None
    if sdf:
        return _rgba(material.findtext("diffuse")) or _rgba(material.findtext("ambient"))
    colour = material.find("color")
    if colour is not None:
        return _rgba(colour.get("rgba"))
    name = material.get("name")
    for named in root.findall("material"):
        if name and named.get("name") == name and named.find("color") is not None:
            return _rgba(named.find("color").get("rgba"))  # type: ignore[union-attr]
    return None


def read_description(path: Path, notes: list[str] | None = None) -> RobotDescription | None:
    """The first link's visual mesh, collision mesh, scale, up axis and name of a URDF or SDF file, or
    None when the file does not parse (why appended to ``notes``: an entity bomb, an external entity, a
    malformed file) or holds no mesh."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        if notes is not None:
            notes.append(unparsed(path, exc))
        return None
    sdf = root.tag == "sdf"
    body = root.find(".//model") if sdf else root
    if body is None:
        return None
    visual = body.find(".//visual")
    visual_uri, scale_text, rpy_text = _mesh_of(visual, sdf)
    collision_uri, _s, _r = _mesh_of(body.find(".//collision"), sdf)
    if visual_uri is None and collision_uri is None:
        return None
    name = (body.get("name") or "").strip() or None
    if name and name.lower().endswith(DESCRIPTION_EXTENSIONS):
        name = name.rsplit(".", 1)[0]
    desc = RobotDescription(path, name, _file_name(visual_uri), _file_name(collision_uri),
                            kind="SDF" if sdf else "URDF")
    for uri in dict.fromkeys(u for u in (visual_uri, collision_uri) if u):
        why = reference_refusal(uri.strip(), path.parent, "mesh path")
        if why:  # it describes a file outside, not the one of that name beside it: not applied, said
            if uri == visual_uri:
                desc.visual = None
            if uri == collision_uri:
                desc.collision = None
            note = (f"{path.name} names the mesh {safe_text(uri.strip())}, outside the library "
                    f"({why.split(' (')[0]}): not read, and the description not applied to {_file_name(uri)} here")
            if notes is not None:
                notes.append(note)
    colour = visual_colour(root, visual, sdf)
    if colour is not None and desc.visual:
        desc.colours[desc.visual] = colour
    scale = _floats(scale_text, 3)
    if scale is not None:
        desc.mesh_scale = (scale[0], scale[1], scale[2])
        if max(scale) - min(scale) > 1e-9 * max(abs(max(scale)), 1.0):
            desc.warnings.append(f"{path.name} scales the mesh unevenly ({scale_text.strip()}): "  # type: ignore[union-attr]
                                 "not applied (state the units in a metadata.json beside it)")
    rpy = _floats(rpy_text, 3) or (0.0, 0.0, 0.0)
    desc.up_axis = up_axis_of_rpy(rpy)
    if desc.up_axis is None:
        desc.warnings.append(f"{path.name} mounts the mesh turned by rpy {rpy_text}: no single up axis")
    return desc


def _file_name(uri: str | None) -> str | None:
    """``package://x/meshes/mug.obj`` or ``model://mug/mug.obj`` -> ``mug.obj`` (matched by file name)."""
    if not uri:
        return None
    return re.split(r"[\\/]", uri.strip())[-1] or None


def unparsed(path: Path, exc: Exception) -> str:
    """The warning of a description file that does not parse: its name and the parser's one-line reason."""
    text = str(exc).splitlines()[0][:200] if str(exc) else ""
    reason = getattr(exc, "strerror", None) or text or type(exc).__name__
    return f"{path.name} does not parse, not used: {reason}"


def descriptions_in(folder_files: list[Path], notes: list[str] | None = None) -> list[RobotDescription]:
    """The readable URDF/SDF files among a folder's files, by name, then the folder's MJCF files read
    together as one description (a body file and its ``*_dependencies.xml`` / includes). A description
    that does not parse is left out, and said in ``notes`` (a warning on the folder's objects)."""
    found = []
    for path in sorted(folder_files):
        if path.suffix.lower() in DESCRIPTION_EXTENSIONS:
            desc = read_description(path, notes)
            if desc is not None:
                found.append(desc)
    xml = [p for p in sorted(folder_files) if p.suffix.lower() == ".xml" and is_mjcf(p)]
    model = read_mjcf(xml, notes) if xml else None
    if model is not None:
        first = model.parts[0][0] if model.parts else None
        desc = RobotDescription(model.files[0], model.name, first, model.collision[0] if model.collision else None,
                                mesh_scale=model.mesh_scale, up_axis="Z", warnings=list(model.warnings),
                                parts=model.parts, collision_files=tuple(model.collision), kind="MJCF",
                                colours=dict(model.colours))
        found.append(desc)
    return found
