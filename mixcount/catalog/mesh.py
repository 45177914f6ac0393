"""Mesh analysis for ingest: load, normalise to metres and Z-up, measure, hash, build a collision mesh
and its convex collision proxy (:mod:`mixcount.catalog.proxies`).

Everything here runs in ingest worker processes: :func:`analyse_model` takes plain arguments and returns
a plain dict, and every failure is an :class:`~mixcount.errors.IngestError` whose ``reason`` becomes the
object's ``error`` column.

Conventions (see docs/ingest.md):

* glTF/GLB is always metres and Y-up (glTF 2.0 spec); a GLB is a scene, and each geometry is placed by
  its node's world transform before anything is measured.
* USD/USDZ carry ``metersPerUnit`` and ``upAxis`` on the stage; mesh prims are placed by their
  local-to-world transform.
* OBJ/PLY/STL carry neither: the caller passes the units and up axis ingest decided
  (:func:`mixcount.catalog.units.decide_units`); where :func:`mixcount.catalog.units.size_prior` allows it
  (an STL), a largest side that is implausible in that unit is re-read in the unit that makes it plausible
  (:func:`mixcount.sizes.plausible_unit`).
* STEP (``.step``/``.stp``) is read through trimesh's loader, which converts it with cascadio
  (OpenCASCADE) into metres, whatever length unit the file states; CAD is Z-up.
* Y-up becomes Z-up the way Blender's glTF importer does it: (x, y, z) -> (x, -z, y).
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.catalog.materials import is_placeholder_image
from mixcount.catalog.mesh_bounds import FullFacts, check_coordinates, cluster_copy, full_facts
from mixcount.catalog.model_files import GLB_MAGIC, Relinked, model_resources, relink_textures  # noqa: F401  (re-exported)
from mixcount.catalog.units import size_prior
from mixcount.errors import IngestError
from mixcount.frame import STEP_EXTENSIONS, UNIT_SCALE, load_model, to_metres_z_up, unit_scale, walk_geometry
from mixcount.sizes import plausible_unit

MESH_EXTENSIONS = (".glb", ".gltf", ".obj", ".ply", ".stl", ".usd", ".usda", ".usdc", ".usdz", ".step", ".stp")
USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")


@dataclass(frozen=True)
class MeshFacts:
    """What ingest records about one model (lengths in metres, Z-up)."""

    source_units: str
    source_up_axis: str
    dim_x: float
    dim_y: float
    dim_z: float
    vertex_count: int
    face_count: int
    watertight: bool
    volume: float | None  # only for watertight meshes; an open mesh has no meaningful volume
    area: float
    textured: bool
    appearance: str  # image | vertex_color | material | none
    geometry_hash: str
    n_parts: int
    collision_path: str
    collision_face_count: int
    proxy_path: str
    proxy_vertex_count: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


# --------------------------------------------------------------------------- loading


@dataclass
class _Parts:
    vertices: list[np.ndarray]
    faces: list[np.ndarray]
    appearance: set[str]


def appearance_of(geom: Any) -> str:
    """How a loaded geometry is coloured: ``image`` (a texture), ``vertex_color`` (colours that vary),
    ``material`` (one colour of its own) or ``none`` (no colour of its own: an STL, an OBJ whose material
    is missing: :func:`mixcount.catalog.materials.is_placeholder_image`)."""
    visual = getattr(geom, "visual", None)
    if visual is None:
        return "none"
    kind = getattr(visual, "kind", None)
    if kind == "texture":
        material = getattr(visual, "material", None)
        image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
        if image is not None and is_placeholder_image(image):
            # trimesh's stand-in for a material nobody wrote (an OBJ with UVs and no .mtl, or its .mtl
            # missing): no colour of the model's own
            return "none"
        if image is not None:
            return "image"
        # glTF COLOR_0 next to a material: trimesh keeps it in visual.vertex_attributes["color"]
        attrs = getattr(visual, "vertex_attributes", None)
        colours = attrs.get("color") if attrs is not None and "color" in attrs else None
        if colours is not None and _varies(colours):
            return "vertex_color"
        return "material"
    if kind in ("vertex", "face"):
        colours = visual.vertex_colors if kind == "vertex" else visual.face_colors
        return "vertex_color" if _varies(colours) else "material"
    return "none"


def _varies(colours: Any) -> bool:
    arr = np.asarray(colours)
    return bool(arr.ndim == 2 and len(arr) > 1 and np.ptp(arr[:, :3], axis=0).max() > 0)


def _load_trimesh(path: Path) -> _Parts:
    import trimesh

    try:
        scene = load_model(path, force="scene")
    except IngestError:
        raise
    except Exception as exc:  # trimesh raises many types for bad files
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise IngestError(f"cannot parse {path.suffix.lower().lstrip('.')} file: {msg[:200]}") from None
    parts = _Parts([], [], set())
    if not scene.geometry:
        raise IngestError(f"no mesh data in file (not a valid {path.suffix.lower().lstrip('.').upper()} model)")
    for _node, transform, geom in walk_geometry(scene):
        parts.vertices.append(trimesh.transform_points(np.asarray(geom.vertices, dtype=np.float64), transform))
        parts.faces.append(np.asarray(geom.faces, dtype=np.int64))
        parts.appearance.add(appearance_of(geom))
    return parts


def _usd_units_name(mpu: float) -> str:
    for name, scale in UNIT_SCALE.items():
        if abs(mpu - scale) <= 1e-9 * max(1.0, scale):
            return name
    return f"{mpu:g}m"


def _load_usd(path: Path) -> tuple[_Parts, float, str]:
    from pxr import Usd, UsdGeom, UsdShade

    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:
        raise IngestError(f"cannot open USD stage: {str(exc).strip().splitlines()[-1][:200]}") from None
    if stage is None:
        raise IngestError("cannot open USD stage")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    up = str(UsdGeom.GetStageUpAxis(stage))
    cache = UsdGeom.XformCache()
    parts = _Parts([], [], set())
    has_texture = any(
        prim.IsA(UsdShade.Shader) and UsdShade.Shader(prim).GetIdAttr().Get() == "UsdUVTexture"
        for prim in stage.Traverse()
    )
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        points = mesh.GetPointsAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if points is None or counts is None or indices is None or len(counts) == 0:
            continue
        pts = np.asarray(points, dtype=np.float64)
        matrix = np.asarray(cache.GetLocalToWorldTransform(prim), dtype=np.float64)  # row-vector convention
        world = np.hstack([pts, np.ones((len(pts), 1))]) @ matrix
        idx = np.asarray(indices, dtype=np.int64)
        tris: list[tuple[int, int, int]] = []
        start = 0
        for n in np.asarray(counts, dtype=np.int64):
            poly = idx[start:start + n]
            tris.extend((int(poly[0]), int(poly[k]), int(poly[k + 1])) for k in range(1, n - 1))
            start += n
        if not tris:
            continue
        parts.vertices.append(world[:, :3])
        parts.faces.append(np.asarray(tris, dtype=np.int64))
        colours = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        values = colours.Get() if colours and colours.HasValue() else None
        if has_texture:
            parts.appearance.add("image")
        elif values is not None and len(values) > 1 and np.ptp(np.asarray(values), axis=0).max() > 0:
            parts.appearance.add("vertex_color")
        else:
            parts.appearance.add("material")
    return parts, mpu, up


@dataclass
class NormalisedMesh:
    """A geometry-only mesh in metres, Z-up, duplicate vertices merged, plus what the source used."""

    mesh: Any  # trimesh.Trimesh
    source_units: str
    source_up_axis: str
    appearance: str
    n_parts: int
    full: FullFacts | None = None  # a big mesh: ``mesh`` is a reduced copy, these facts are of the whole


def load_normalised(path: Path, *, units: str = "m", up_axis: str = "Y", face_budget: int = 0) -> NormalisedMesh:
    """Load any supported model and return it in metres, Z-up. ``units`` applies only to formats that
    carry none (OBJ/PLY/STL); ``up_axis`` to those and to glTF, whose Y-up rule it overrides (ingest
    passes Y for a glTF unless the object's up axis was stated: :func:`mixcount.frame.source_frame`).
    ``face_budget`` > 0: a mesh of more faces is measured whole where that is cheap and returned as a
    reduced copy (:mod:`mixcount.catalog.mesh_bounds`)."""
    import trimesh

    suffix = path.suffix.lower()
    if suffix in USD_EXTENSIONS:
        parts, scale, up = _load_usd(path)
        units = _usd_units_name(scale)
    elif suffix in (".glb", ".gltf"):
        try:  # metres by the glTF specification, unless a unit was stated (a derived GLB keeps its source's)
            scale = unit_scale(units or "m")
        except ValueError as exc:
            raise IngestError(str(exc)) from None
        parts = _load_trimesh(path)
        up = up_axis.upper()
    elif suffix in STEP_EXTENSIONS:
        parts = _load_trimesh(path)  # cascadio converts the STEP's own length unit into metres
        scale, units, up = 1.0, "m", up_axis.upper()
    elif suffix in (".obj", ".ply", ".stl"):
        try:
            scale = unit_scale(units)
        except ValueError as exc:
            raise IngestError(str(exc)) from None
        parts = _load_trimesh(path)
        up = up_axis.upper()
    else:
        raise IngestError(f"unsupported model format {suffix or '(no extension)'}")
    if not parts.faces:
        raise IngestError("mesh has no faces")
    appearance_kinds = set(parts.appearance)
    offsets = np.cumsum([0] + [len(v) for v in parts.vertices[:-1]])
    vertices = np.vstack(parts.vertices) * scale
    faces = np.vstack([f + o for f, o in zip(parts.faces, offsets)])
    check_coordinates(vertices)  # inf / nan / absurdly far: broken, with the reason (mesh_bounds)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise IngestError("mesh has face indices outside its vertex list")
    try:
        vertices = to_metres_z_up(vertices, 1.0, up)
    except ValueError as exc:
        raise IngestError(str(exc)) from None
    n_parts = len(parts.faces)
    del parts
    full, vertices, faces = _bounded(vertices, faces, face_budget)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)  # merges duplicate vertices
    if len(mesh.faces) == 0:
        raise IngestError("mesh has no faces")
    if not mesh.area > 0:
        raise IngestError("mesh is degenerate: zero surface area")
    rank = ("image", "vertex_color", "material", "none")
    appearance = min(appearance_kinds, key=rank.index) if appearance_kinds else "none"
    return NormalisedMesh(mesh, units, up, appearance, n_parts, full)


def _bounded(vertices: np.ndarray, faces: np.ndarray, face_budget: int) -> tuple[FullFacts | None, np.ndarray, np.ndarray]:
    """(facts of the whole mesh, a reduced copy) above ``face_budget`` faces; (None, the mesh) within it."""
    if face_budget <= 0 or len(faces) <= face_budget:
        return None, vertices, faces
    full = full_facts(vertices, faces)
    if not full.area > 0:
        raise IngestError("mesh is degenerate: zero surface area")
    v, f = cluster_copy(vertices, faces, face_budget, full.area)
    return replace(full, copy_faces=int(len(f))), v, f


# --------------------------------------------------------------------------- facts


def geometry_hash(mesh: Any) -> str:
    """SHA-256 of the normalised geometry: vertices relative to the bbox minimum, rounded to 1 µm,
    and the faces. Equal for the same shape however it was coloured, textured or placed."""
    v = np.round(np.asarray(mesh.vertices) - mesh.bounds[0], 6) + 0.0  # + 0.0 folds -0.0 into 0.0
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(v, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype="<i8").tobytes())
    return h.hexdigest()


def _ply_face_count(path: Path) -> int | None:
    try:
        with open(path, "rb") as fh:
            for _ in range(64):
                line = fh.readline()
                if not line or line.strip() == b"end_header":
                    break
                if line.startswith(b"element face"):
                    return int(line.split()[-1])
    except (OSError, ValueError):
        return None
    return None


COLLISION_INPUT_FACTOR = 50  # the quadric collapse starts from at most this many x its face budget


def build_collision_mesh(mesh: Any, out_path: Path, face_budget: int) -> int:
    """Clean zero-area faces, quadric-edge-collapse to ``face_budget`` faces, write a binary PLY.

    A mesh of more than :data:`COLLISION_INPUT_FACTOR` x ``face_budget`` faces is first reduced to about
    that many by vertex clustering (:func:`mixcount.catalog.mesh_bounds.cluster_copy`, cells of ~1/200 of a
    10 cm object at the default budget): the quadric collapse of an 887k-face capture to 2,000 faces took
    21.7 CPU-s of its 26 s ingest, from a 100k-face clustered copy 2.7 s, and came as close to the mesh
    (p95 surface distance 2.0 mm vs 2.3 mm on an 11 cm capture; hull volume 0.1 % vs 10 % under;
    docs/performance.md, "Ingest of DTC-sized captures").

    Written to a temporary name and renamed, so a killed worker never leaves half a file; an existing
    file (same geometry hash and budget in its name) is reused.
    """
    import pymeshlab

    if out_path.exists():
        count = _ply_face_count(out_path)
        if count is not None:
            return count
    out_path.parent.mkdir(parents=True, exist_ok=True)
    vertices, faces = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    start = COLLISION_INPUT_FACTOR * max(int(face_budget), 1)
    if len(faces) > start:
        vertices, faces = cluster_copy(vertices, faces, start, float(mesh.area))
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    ms.meshing_remove_null_faces()
    ms.meshing_remove_unreferenced_vertices()
    if ms.current_mesh().face_number() == 0:
        raise IngestError("mesh has only zero-area faces")
    if ms.current_mesh().face_number() > face_budget:
        ms.meshing_decimation_quadric_edge_collapse(
            targetfacenum=int(face_budget), preservenormal=True, planarquadric=True, autoclean=True
        )
    with atomic_path(out_path) as tmp:
        ms.save_current_mesh(str(tmp), binary=True, save_vertex_color=False, save_vertex_normal=False)
    return int(ms.current_mesh().face_number())


def analyse_model(
    model_path: str,
    *,
    collision_dir: str,
    face_budget: int,
    units: str,
    up_axis: str,
    proxy_max_vertices: int,
    facts_face_budget: int,
    collision_source: str | None = None,
    units_reason: str = "",
    size_hint: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Worker entry point: all facts of one model as a plain dict (raises IngestError).

    ``units``/``units_reason``: the unit ingest decided and why; where the reason lets the size prior re-read
    it (:func:`mixcount.catalog.units.size_prior`: an STL's assumed millimetres) a largest side implausible in
    it is re-read in the unit that makes it plausible, and the facts say so (``units_reason`` starts with
    ``size prior``); an assumed unit of another kind is only said to be implausible.

    ``collision_source``: a collision mesh shipped beside the model (``mug_col.obj``, ``duck_vhacd.obj``),
    read in the model's frame; the collision mesh and proxy are built from it instead of the visual mesh
    when its box agrees with the model's (:func:`_companion_collision`).

    ``facts_face_budget`` > 0: a model of more faces is measured whole where that is cheap, its hash and
    collision mesh come from a reduced copy, and ``facts_note`` says so (:mod:`mixcount.catalog.mesh_bounds`).
    Numerical warnings of the libraries are not printed: they are kept in ``facts_note``.

    ``size_hint`` (name, category, a stated size and who stated it): the object's real size and its source
    (:func:`mixcount.catalog.typical_sizes.size_decision`: stated, the model's, its kind's typical size, or
    none), the model scaled to it (its unit then metres per unit as a number; ``size_source`` in the facts)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        facts = _analyse(model_path, collision_dir=collision_dir, face_budget=face_budget, units=units,
                         up_axis=up_axis, proxy_max_vertices=proxy_max_vertices, collision_source=collision_source,
                         facts_face_budget=facts_face_budget, units_reason=units_reason, size_hint=size_hint)
    said = sorted({f"{w.message} ({Path(w.filename).name}:{w.lineno})" for w in caught
                   if issubclass(w.category, RuntimeWarning)})
    if said:  # not on stderr: on the object, where the user looks for what ingest met
        facts["facts_note"] = "; ".join(filter(None, [facts.get("facts_note"), "numerical warnings: " + "; ".join(said[:3])]))
    return facts


def _analyse(model_path: str, *, collision_dir: str, face_budget: int, units: str, up_axis: str,
             proxy_max_vertices: int, collision_source: str | None, facts_face_budget: int,
             units_reason: str, size_hint: dict[str, Any] | None = None) -> dict[str, Any]:
    from mixcount.catalog.typical_sizes import sized

    path = Path(model_path)
    norm = load_normalised(path, units=units, up_axis=up_axis, face_budget=facts_face_budget)
    prior = size_prior(units_reason)  # None for what the user said: never second-guessed
    if prior is not None:
        norm, units_reason = _size_prior(norm, units_reason, apply=prior == "reread")
        units = norm.source_units
    norm, units_reason, size_source = sized(norm, units_reason, size_hint)  # the real size and its source
    units = norm.source_units
    mesh, full = norm.mesh, norm.full
    ghash = geometry_hash(mesh)
    dims = mesh.extents if full is None else np.asarray(full.extents)
    watertight = bool(mesh.is_watertight) if full is None else full.watertight
    volume = (float(abs(mesh.volume)) if watertight else None) if full is None else full.volume
    source_mesh, used, key = mesh, None, ghash
    if collision_source:
        companion = _companion_collision(mesh, Path(collision_source), units=units, up_axis=up_axis,
                                         face_budget=facts_face_budget)
        if companion is not None:
            source_mesh, used = companion, str(Path(collision_source).resolve())
            key = hashlib.sha256(f"{ghash}|{geometry_hash(companion)}".encode()).hexdigest()
    collision = Path(collision_dir) / f"{key[:32]}_{int(face_budget)}.ply"
    collision_faces = build_collision_mesh(source_mesh, collision, int(face_budget))
    from mixcount.catalog.proxies import proxy_from_collision

    proxy = proxy_from_collision(collision, key, Path(collision_dir), int(proxy_max_vertices))
    facts = MeshFacts(
        source_units=norm.source_units,
        source_up_axis=norm.source_up_axis,
        dim_x=float(dims[0]),
        dim_y=float(dims[1]),
        dim_z=float(dims[2]),
        vertex_count=int(len(mesh.vertices)) if full is None else full.vertex_count,
        face_count=int(len(mesh.faces)) if full is None else full.face_count,
        watertight=watertight,
        volume=volume,
        area=float(mesh.area) if full is None else full.area,
        textured=norm.appearance in ("image", "vertex_color"),
        appearance=norm.appearance,
        geometry_hash=ghash,
        n_parts=norm.n_parts,
        collision_path=str(collision.resolve()),
        collision_face_count=collision_faces,
        proxy_path=proxy.path,
        proxy_vertex_count=proxy.vertex_count,
    )
    return {**facts.as_dict(), "collision_source": used, "units_reason": units_reason, "size_source": size_source,
            "facts_note": None if full is None else full.note()}


def _size_prior(norm: NormalisedMesh, reason: str, *, apply: bool) -> tuple[NormalisedMesh, str]:
    """``norm`` re-read in the unit that makes its largest side plausible when the assumed unit does not
    (:func:`mixcount.sizes.plausible_unit`), with the reason that says so; unchanged otherwise. Without
    ``apply`` the reason only says which unit would make it plausible (the unit is said, not changed)."""
    try:
        assumed_scale = unit_scale(norm.source_units)
    except ValueError:
        return norm, reason
    largest = float(norm.mesh.extents.max()) / assumed_scale  # in the file's own numbers
    unit = plausible_unit(largest, norm.source_units) if norm.source_units in UNIT_SCALE else None
    if unit is None or unit == norm.source_units:
        return norm, reason
    if not apply:
        return norm, (f"{reason}; its largest side, {largest * assumed_scale:.3g} m, is no everyday object's: "
                      f"read as {unit} it would be {largest * UNIT_SCALE[unit]:.3g} m (catalog ingest --units)")
    factor = UNIT_SCALE[unit] / assumed_scale
    norm.mesh.apply_scale(factor)
    full = norm.full
    if full is not None:  # the whole mesh's facts in the new unit too
        full = replace(full, extents=tuple(float(e) * factor for e in full.extents),
                                   area=full.area * factor ** 2,
                                   volume=None if full.volume is None else full.volume * factor ** 3)
    why = (f"size prior: {largest * assumed_scale:.3g} m read as {norm.source_units} is no everyday object's "
           f"size; read as {unit} it is {largest * UNIT_SCALE[unit]:.3g} m (was: {reason or 'assumed'})")
    return NormalisedMesh(norm.mesh, unit, norm.source_up_axis, norm.appearance, norm.n_parts, full), why


def _companion_collision(mesh: Any, path: Path, *, units: str, up_axis: str, face_budget: int = 0) -> Any | None:
    """The collision companion in the model's frame, or None when it does not load or its box is not
    the model's (within 25 % of the largest extent: a companion of another scale or pose is not used)."""
    try:
        companion = load_normalised(path, units=units, up_axis=up_axis, face_budget=face_budget).mesh
    except IngestError:
        return None
    size = float(max(mesh.extents.max(), 1e-12))
    if np.abs(np.asarray(companion.bounds) - np.asarray(mesh.bounds)).max() > 0.25 * size:
        return None
    return companion
