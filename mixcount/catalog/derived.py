"""Derived models: one GLB for an object whose source is a STEP file or several part files.

Every later step (mesh analysis, the canonical render in Blender, the USD asset) reads one model file
in one frame. A STEP file is read by cascadio (OpenCASCADE, into metres) into one glTF primitive per
colour of each solid (:func:`load_step`); the parts of a multi-part object (:mod:`mixcount.catalog.layouts.parts`) are placed in their common frame,
each by its description's placement when it has one. The result is written once, as a GLB named by a
hash of the sources (and their placements), under the catalog's ``staged/derived`` folder; the object's
``model_path`` points at it and ``metadata.source_model_path`` / ``metadata.parts`` name the sources.

A derived GLB keeps its sources' numbers (millimetres stay millimetres, CAD's Z-up stays Z-up): the unit
and up axis recorded for the object apply to it (:func:`mixcount.frame.source_frame`), so that the
unit decision is the same whatever was derived.

Every material is kept (issue 70): each primitive of a source, with its material, stays a geometry of
its own in the derived GLB. trimesh's STEP loader merged the primitives of a solid into one geometry,
which kept only the first colour (an LED's leads red, an IC's pins black); :func:`load_step` reads the
STEP without that merge. docs/usd.md ("Materials kept") has the counts per source kind.
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.frame import STEP_EXTENSIONS, load_model

DERIVE_VERSION = 2  # 2: every colour of a STEP kept (load_step)

RGBA = tuple[float, float, float, float]


def needs_derived(cand: Any) -> bool:
    """True for an object made of parts or read from a STEP file, or one whose model carries no colour
    that its description (URDF/SDF/MJCF) gives (:func:`uncoloured`)."""
    if cand.model_path is None or cand.error:
        return False
    if bool(cand.parts) or Path(cand.model_path).suffix.lower() in STEP_EXTENSIONS:
        return True
    colour = _colour_of(getattr(cand, "colours", {}), Path(cand.model_path))
    return colour is not None and uncoloured(Path(cand.model_path))


def _colour_of(colours: dict[str, RGBA], path: Path) -> RGBA | None:
    """The description's colour of a source, matched by file name (a staged copy keeps its name)."""
    return colours.get(path.name) if colours else None


def uncoloured(path: Path) -> bool:
    """True when some geometry of the model has no colour of its own (no texture, vertex or material
    colour: an STL, an OBJ without its .mtl), so a description's colour would be the only one it has."""
    from mixcount.catalog.mesh import appearance_of

    try:
        scene = _load_source(path)
    except Exception:  # noqa: BLE001 - a model that does not load is reported by build_glb / the analysis
        return False
    return any(appearance_of(g) == "none" for g in scene.geometry.values())


def _key(sources: list[tuple[Path, Any]], colours: dict[str, RGBA] | None = None) -> str:
    h = hashlib.sha256(f"derived-v{DERIVE_VERSION}".encode())
    for name, rgba in sorted((colours or {}).items()):
        h.update(f"colour:{name}:{','.join(f'{v:.6g}' for v in rgba)}\0".encode())
    for path, matrix in sources:
        h.update(path.name.encode() + b"\0")
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        if matrix is not None:
            h.update(np.ascontiguousarray(np.asarray(matrix, dtype="<f8")).tobytes())
    return h.hexdigest()


def load_step(path: Path) -> Any:
    """A STEP file as a trimesh Scene in metres: one geometry per colour of each solid, each with its
    material (the file's colour as a glTF PBR factor). cascadio writes one primitive per colour
    (``merge_primitives`` merges faces of the same colour only); trimesh's own STEP loader then merged
    those primitives into one geometry with the first one's material, which this does not."""
    import cascadio
    import trimesh

    glb = cascadio.load(path.read_bytes(), file_type="step", merge_primitives=True)
    if not glb:
        raise ValueError(f"OpenCASCADE could not read {path.name} as STEP")
    return trimesh.load(io.BytesIO(glb), file_type="glb", merge_primitives=False, process=False)


def _load_source(path: Path) -> Any:
    return load_step(path) if path.suffix.lower() in STEP_EXTENSIONS else load_model(path, force="scene")


def _described_colour(geom: Any, rgba: RGBA | None) -> Any:
    """``geom`` in the description's colour where it has none of its own (a PBR material whose base
    colour is ``rgba``); a textured or coloured geometry keeps its own, as robot viewers show it."""
    from mixcount.catalog.mesh import appearance_of

    if rgba is None or appearance_of(geom) != "none":
        return geom
    import trimesh

    factor = [int(round(255 * min(max(v, 0.0), 1.0))) for v in rgba]
    geom.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(name="description_colour", baseColorFactor=factor))
    return geom


def build_glb(sources: list[tuple[Path, Any]], out: Path, colours: dict[str, RGBA] | None = None) -> None:
    """One GLB of every source's geometry, each placed by its 4x4 matrix (None: as it is), each geometry
    without a colour of its own in the colour ``colours`` gives its source's file name (a description's,
    :func:`_described_colour`); raises ValueError naming the source that does not load."""
    import trimesh

    scene = trimesh.Scene()
    for k, (path, matrix) in enumerate(sources):
        try:
            part = _load_source(path)
        except Exception as exc:  # trimesh raises many types for bad files
            raise ValueError(f"cannot read part {path.name}: {str(exc).strip()[:200] or type(exc).__name__}") from None
        place = np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64)
        for j, node in enumerate(part.graph.nodes_geometry):
            transform, geom_name = part.graph[node]
            geom = part.geometry.get(geom_name)
            if geom is None:
                continue
            # numbered first: names cut to 60 characters must stay distinct, or a later geometry replaces an
            # earlier one (a KiCad name such as BarrelJack_CUI_PJ-063AH_Horizontal lost its body that way)
            scene.add_geometry(_described_colour(geom.copy(), _colour_of(colours or {}, path)), node_name=f"{k:02d}_{j:03d}_{path.stem}_{node}"[:60],
                               geom_name=f"{k:02d}_{j:03d}_{path.stem}_{geom_name}"[:60], transform=place @ transform)
    if not scene.geometry:
        raise ValueError("no mesh data in the parts")
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(scene.export(file_type="glb"))


def _source_warnings(cand: Any, sources: list[tuple[Path, Any]]) -> None:
    """What ingest tolerates in each source file (an OBJ's missing or refused .mtl or texture) onto the
    object's warnings: the catalog's model is the derived GLB, whose own check no longer sees them."""
    from mixcount.catalog.model_files import model_resources
    from mixcount.errors import IngestError

    for path, _matrix in sources:
        if path.suffix.lower() != ".obj":
            continue
        roots = getattr(cand, "roots", None)
        if roots is not None and not roots.contains(path):  # a staged copy: its folder too
            roots = roots.widened(path.parent)
        found: list[str] = []
        try:
            model_resources(path, found, roots)
        except (IngestError, OSError):
            continue  # the file itself does not read: build_glb says so
        cand.warnings.extend(w for w in found if w not in cand.warnings)


def derive(cand: Any, staging_root: Path) -> None:
    """Point ``cand.model_path`` at its derived GLB (written when missing); a source that does not load
    makes the object broken with the reason."""
    if not needs_derived(cand):
        return
    sources = list(cand.parts) if cand.parts else [(Path(cand.model_path), None)]
    _source_warnings(cand, sources)
    colours = {p.name: c for p, _m in sources if (c := _colour_of(getattr(cand, "colours", {}), p)) is not None}
    try:
        out = staging_root / "derived" / f"{_key(sources, colours)[:32]}.glb"
        if not out.is_file():
            build_glb(sources, out, colours)
    except (OSError, ValueError) as exc:
        cand.error = str(exc) if isinstance(exc, ValueError) else f"cannot derive a model: {exc}"
        return
    cand.metadata.setdefault("source_model_path", str(cand.model_path))
    cand.model_path = out
