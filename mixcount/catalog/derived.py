"""Derived models: one GLB for an object whose source is a STEP file or several part files.

Every later step (mesh analysis, the canonical render in Blender, the USD asset) reads one model file
in one frame. A STEP file is read through trimesh's loader (cascadio / OpenCASCADE, into metres); the
parts of a multi-part object (:mod:`mixcount.catalog.layouts.parts`) are placed in their common frame,
each by its description's placement when it has one. The result is written once, as a GLB named by a
hash of the sources (and their placements), under the catalog's ``staged/derived`` folder; the object's
``model_path`` points at it and ``metadata.source_model_path`` / ``metadata.parts`` name the sources.

A derived GLB keeps its sources' numbers (millimetres stay millimetres, CAD's Z-up stays Z-up): the unit
and up axis recorded for the object apply to it (:func:`mixcount.frame.source_frame`), so that the
unit decision is the same whatever was derived.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.frame import STEP_EXTENSIONS, load_model

DERIVE_VERSION = 1


def needs_derived(cand: Any) -> bool:
    """True for an object made of parts or read from a STEP file."""
    return (cand.model_path is not None and not cand.error
            and (bool(cand.parts) or Path(cand.model_path).suffix.lower() in STEP_EXTENSIONS))


def _key(sources: list[tuple[Path, Any]]) -> str:
    h = hashlib.sha256(f"derived-v{DERIVE_VERSION}".encode())
    for path, matrix in sources:
        h.update(path.name.encode() + b"\0")
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        if matrix is not None:
            h.update(np.ascontiguousarray(np.asarray(matrix, dtype="<f8")).tobytes())
    return h.hexdigest()


def build_glb(sources: list[tuple[Path, Any]], out: Path) -> None:
    """One GLB of every source's geometry, each placed by its 4x4 matrix (None: as it is); raises
    ValueError naming the source that does not load."""
    import trimesh

    scene = trimesh.Scene()
    for k, (path, matrix) in enumerate(sources):
        try:
            part = load_model(path, force="scene")
        except Exception as exc:  # trimesh raises many types for bad files
            raise ValueError(f"cannot read part {path.name}: {str(exc).strip()[:200] or type(exc).__name__}") from None
        place = np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64)
        for node in part.graph.nodes_geometry:
            transform, geom_name = part.graph[node]
            geom = part.geometry.get(geom_name)
            if geom is None:
                continue
            scene.add_geometry(geom.copy(), node_name=f"{k:02d}_{path.stem}_{node}"[:60],
                               geom_name=f"{k:02d}_{path.stem}_{geom_name}"[:60], transform=place @ transform)
    if not scene.geometry:
        raise ValueError("no mesh data in the parts")
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(scene.export(file_type="glb"))


def derive(cand: Any, staging_root: Path) -> None:
    """Point ``cand.model_path`` at its derived GLB (written when missing); a source that does not load
    makes the object broken with the reason."""
    if not needs_derived(cand):
        return
    sources = list(cand.parts) if cand.parts else [(Path(cand.model_path), None)]
    try:
        out = staging_root / "derived" / f"{_key(sources)[:32]}.glb"
        if not out.is_file():
            build_glb(sources, out)
    except (OSError, ValueError) as exc:
        cand.error = str(exc) if isinstance(exc, ValueError) else f"cannot derive a model: {exc}"
        return
    cand.metadata.setdefault("source_model_path", str(cand.model_path))
    cand.model_path = out
