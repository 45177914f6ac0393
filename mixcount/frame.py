"""One normalisation of a model's frame: units -> metres, up axis -> Z-up, one walk over its nodes.

Ingest (:mod:`mixcount.catalog.mesh`, mesh facts and collision meshes) and USD conversion
(:mod:`mixcount.usd.assets`, the render asset) must place a model identically, or the collision mesh
and the visual drift apart. Both use these functions. Pure numpy; trimesh only for the node walk.

Rules: glTF/GLB are metres and Y-up by specification, unless a unit or an up axis is stated for the
object (``units`` / ``up_axis`` in its ``metadata.json``, ``catalog ingest --units`` / ``--up-axis``:
exporters that write centimetres or Z-up geometry into a GLB are common; ingest's derived GLB of a STEP
model or of a folder's parts keeps its source's numbers and records their unit); USD carries ``metersPerUnit`` and ``upAxis``; OBJ/PLY/STL carry
neither, so the ingest settings (``ingest.assume_units``, ``ingest.assume_up_axis``) or the values
recorded for the object apply. A Y-up frame becomes Z-up as Blender's glTF importer does
it: (x, y, z) -> (x, -z, y).
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Optional

import numpy as np

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
UP_AXES = ("X", "Y", "Z")
GLTF_EXTENSIONS = (".glb", ".gltf")
STEP_EXTENSIONS = (".step", ".stp")  # CAD exchange (ISO 10303), read through trimesh + cascadio


def up_axis_rotation(up: str) -> np.ndarray:
    """3x3 rotation taking a ``up``-up frame to Z-up; raises ValueError for anything but X, Y, Z."""
    up = (up or "").upper()
    if up == "Z":
        return np.eye(3)
    if up == "Y":  # (x, y, z) -> (x, -z, y)
        return np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    if up == "X":  # (x, y, z) -> (-z, y, x)
        return np.array([[0, 0, -1.0], [0, 1.0, 0], [1.0, 0, 0]])
    raise ValueError(f"unknown up axis {up!r} (expected X, Y or Z)")


def unit_scale(units: str) -> float:
    """Metres per unit for a unit name, or for a positive number written as text (``"0.05"``: the scale a
    URDF/SDF beside the model gives its mesh); raises ValueError for anything else."""
    try:
        return UNIT_SCALE[units.lower()]
    except KeyError:
        pass
    try:
        value = float(units)
    except ValueError:
        value = float("nan")
    if value > 0 and value < float("inf"):
        return value
    raise ValueError(f"unknown units {units!r} (expected one of {', '.join(UNIT_SCALE)}, or metres per unit "
                     "as a positive number)") from None


GLTF_UP_AXIS = "Y"  # the glTF specification's up axis


def source_frame(model_path: Path, units: Optional[str], up_axis: Optional[str]) -> tuple[float, str, str]:
    """(metres per unit, units name, up axis) of a non-USD model file: glTF is metres by its spec and
    Y-up unless ``units`` / ``up_axis`` (the object's recorded unit and axis) say otherwise; the rest use
    ``units``/``up_axis`` (defaults m / Y when nothing was recorded)."""
    if model_path.suffix.lower() in GLTF_EXTENSIONS:
        name = (units or "m").lower()
        return unit_scale(name), name, (up_axis or GLTF_UP_AXIS).upper()
    name = (units or "m").lower()
    return unit_scale(name), name, (up_axis or "Y").upper()


def load_model(path: Path | str, *, force: Optional[str] = None, roots: Any = None) -> Any:
    """``trimesh.load`` of a model file (``process=False``) whose references (an OBJ's .mtl and its textures,
    a glTF's buffers and images) are read through :class:`BoundedResolver`: where the file says, as Blender
    and MuJoCo read them, also outside the model's own folder (robosuite ships ``objects/meshes/can.mtl``
    naming ``../../textures/soda.png``; trimesh's own resolver drops such a texture with only a log line),
    but never outside the library: with ``roots`` (a :class:`mixcount.library_root.LibraryRoots`, else the
    roots of the ingest step under way, :func:`mixcount.library_root.current`) a reference that leaves them
    is not read; without any, an absolute path or a URI (``file://``) is not read (a catalog's models were
    sealed by ingest: every relative reference they hold was checked inside their library). Every reader
    of a library's model file goes through here (ingest, the USD conversion, curation, captions)."""
    import trimesh

    resolver = BoundedResolver(str(path), roots)
    if force is None:
        return trimesh.load(str(path), process=False, resolver=resolver)
    return trimesh.load(str(path), force=force, process=False, resolver=resolver)


def _bounded_resolver() -> Any:
    import trimesh

    from mixcount.library_root import LibraryRoots, OutsideLibraryError, current

    class _Bounded(trimesh.resolvers.FilePathResolver):  # type: ignore[misc, name-defined]
        """trimesh's file resolver whose every reference goes through the library's roots
        (:meth:`mixcount.library_root.LibraryRoots.resolve`); a refused one is a ValueError, which trimesh
        takes as "not there" (a texture: the model loads untextured; a buffer: the load fails)."""

        def __init__(self, source: str, roots: Any = None) -> None:
            super().__init__(source, allow_anywhere=True)
            self.roots = roots if roots is not None else current()

        def namespaced(self, namespace: str) -> Any:
            return type(self)(os.path.join(self.parent, namespace), self.roots)

        def absolute(self, name: str) -> Path:
            ref = name.strip()
            try:
                if self.roots is not None:
                    return Path(self.roots.resolve(ref, self.parent, "reference"))
                # no roots: a relative reference as written; never an absolute path or a URI
                LibraryRoots(("/",)).resolve(ref, self.parent, "reference")
            except OutsideLibraryError as exc:
                raise ValueError(str(exc)) from None
            if os.path.isabs(ref) or ref.lower().startswith("file:"):
                raise ValueError(f"{ref}: an absolute reference is not read")
            return (Path(self.parent) / ref).resolve()

    return _Bounded


def BoundedResolver(source: str, roots: Any = None) -> Any:  # noqa: N802  (a class, built on first use)
    """A trimesh resolver for a model file at ``source`` that reads no reference outside ``roots`` (see
    :func:`load_model`)."""
    global _BOUNDED
    if _BOUNDED is None:
        _BOUNDED = _bounded_resolver()
    return _BOUNDED(source, roots)


_BOUNDED: Any = None


@contextmanager
def quiet_native_output() -> Iterator[None]:
    """File descriptors 1 and 2 sent to /dev/null for the block: OpenCASCADE (cascadio, a STEP read) prints
    its parser's complaints (``**** ERR StepFile : Undefined Parsing ...``) straight to them, past Python.
    The reason a file does not read reaches the user as the object's one-line broken reason instead."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def walk_geometry(scene: Any) -> Iterator[tuple[str, np.ndarray, Any]]:
    """(node name, 4x4 world transform, trimesh.Trimesh) for every triangle mesh of a trimesh Scene,
    in the file's node order (deterministic, and the same for ingest and conversion). Not sorted by
    name: "part_10" would come before "part_2", and the face order feeds the stratified surface
    sampling of the curation descriptors."""
    import trimesh

    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if isinstance(geom, trimesh.Trimesh) and len(geom.faces) > 0:
            yield node, np.asarray(transform, dtype=np.float64), geom


def to_metres_z_up(points: np.ndarray, scale: float, up: str) -> np.ndarray:
    """Source points (N, 3) in the model's units and up axis -> metres, Z-up."""
    return (np.asarray(points, dtype=np.float64) * scale) @ up_axis_rotation(up).T
