"""Which way is up, and why: the up axis of every ingested object with the reason it was chosen.

Formats that carry an up axis keep it (glTF's Y by the specification, USD's ``upAxis``). For the rest
(OBJ/PLY/STL) the evidence is taken in this order, the first that speaks decides:

1. ``up_axis`` in the object's ``metadata.json`` (or a layout's convention: OmniObject3D, GSO);
2. ``catalog ingest --up-axis`` for the folders given, kept in the catalog (table ``source_folders``):
   a later ingest of the folder, or of a folder inside it, without the option keeps it; ``--up-axis
   auto`` forgets it;
3. a URDF/SDF beside the mesh (robot and simulator bodies are Z-up; the visual's ``rpy`` says which mesh
   axis it turns up: :mod:`mixcount.catalog.layouts.companions`);
4. an STL or STEP file is Z-up (CAD and 3D-printing tools write Z-up);
5. ``ingest.assume_up_axis``; then, for an OBJ/PLY container (tray, bowl) read by that rule whose opening
   faces another positive axis of the file (:func:`opening_up_axis`), that axis: a container opens
   upward. Ingest measures it again in that frame, and a later ingest keeps it (:func:`kept_evidence`).

glTF files use rule 1 and 2 only (their specification is rule 6). The chosen axis and its reason are
recorded in the object's ingest info (``up_axis_reason``, ``catalog show``).
"""

from __future__ import annotations

import os
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.layouts import Candidate
from mixcount.catalog.models import STATUS_ACTIVE, CatalogObject, SourceFolder, utcnow
from mixcount.errors import IngestError
from mixcount.frame import GLTF_EXTENSIONS, GLTF_UP_AXIS, UP_AXES


def check_up_axis(value: str | None) -> str | None:
    """``--up-axis`` checked: X, Y or Z (upper case), None for ``auto`` or nothing; IngestError otherwise."""
    if value is None or value.strip().lower() == "auto":
        return None
    up = value.strip().upper()
    if up not in UP_AXES:
        raise IngestError(f"unknown up axis {value!r}: give X, Y, Z or auto")
    return up


OPENING_REASON = "its opening faces +{axis} of the file (a container opens upward)"


def opening_up_axis(collision_path: str, up: str) -> str | None:
    """The file axis (X, Y, Z) a container's opening faces, when it is a positive axis other than ``up``
    (the axis the collision mesh was read with), else None. The collision mesh is in the catalog's Z-up
    frame: the opening's direction is turned back into the file's frame."""
    import numpy as np

    from mixcount.catalog.containers import OPENING_UP_MIN_Z, opening_direction
    from mixcount.frame import up_axis_rotation

    try:
        vec = opening_direction(collision_path)
    except Exception:  # an unreadable collision mesh: no evidence (reported elsewhere)
        return None
    if vec is None or vec[2] >= OPENING_UP_MIN_Z:
        return None
    in_file = up_axis_rotation(up).T @ np.asarray(vec)
    k = int(np.argmax(np.abs(in_file)))
    if in_file[k] < OPENING_UP_MIN_Z or "XYZ"[k] == up.upper():
        return None  # a negative axis (the frame rule has only X, Y, Z) or no clear one
    return "XYZ"[k]


def turn_by_openings(session: Session, candidates: list[Candidate], *, assume: str) -> list[Candidate]:
    """The candidates of this run left to ``ingest.assume_up_axis`` (OBJ/PLY) that are active containers
    whose opening faces another positive axis of the file, with that axis and its reason set."""
    out = []
    for cand in candidates:
        if cand.error or cand.model_path is None or cand.up_axis is not None:
            continue
        if Path(cand.metadata.get("source_model_path") or cand.model_path).suffix.lower() not in (".obj", ".ply"):
            continue
        row = session.scalars(select(CatalogObject).where(CatalogObject.source == cand.source,
                                                          CatalogObject.source_id == cand.source_id)).one_or_none()
        if row is None or not row.container or row.status != STATUS_ACTIVE or not row.collision_path:
            continue
        axis = opening_up_axis(row.collision_path, row.source_up_axis or assume)
        if axis is not None:
            cand.up_axis, cand.up_reason = axis, OPENING_REASON.format(axis=axis)
            out.append(cand)
    return out


def kept_evidence(cand: Candidate, stored_up: str | None, stored_reason: str | None) -> None:
    """A candidate left to ``ingest.assume_up_axis`` whose stored row was turned by its opening keeps that
    axis (so that a rerun finds it unchanged instead of measuring it twice)."""
    if cand.up_axis is None and stored_up and (stored_reason or "").startswith("its opening faces"):
        cand.up_axis, cand.up_reason = stored_up, stored_reason


def orient(session: Session, candidates: list[Candidate], paths: list, up_axis: str | None, *, assume: str) -> None:
    """Remember (``--up-axis X|Y|Z``) or forget (``auto``) the stated axis for ``paths``, then choose every
    candidate's up axis and reason (:func:`choose_up_axis`); commits."""
    stated = check_up_axis(up_axis)
    given = [Path(p).expanduser().resolve() for p in paths]
    if stated:
        remember_up_axis(session, given, stated)
    elif up_axis is not None:  # "auto": forget what was stated for these paths
        forget_inside(session, given)
    axes = folder_axes(session)
    for cand in candidates:
        choose_up_axis(cand, stated_now=stated, axes=axes, assume=assume)


def remember_up_axis(session: Session, paths: list[Path], up_axis: str | None) -> None:
    """Record (or with None forget) the up axis stated for these paths (folders or model files); commits."""
    for path in paths:
        key = os.path.abspath(path)
        row = session.scalars(select(SourceFolder).where(SourceFolder.path == key)).one_or_none()
        if up_axis is None:
            if row is not None:
                session.delete(row)
            continue
        if row is None:
            row = SourceFolder(path=key)
            session.add(row)
        row.up_axis, row.updated_at = up_axis, utcnow()
    session.commit()


def forget_inside(session: Session, paths: list[Path]) -> None:
    """``--up-axis auto``: forget the stated axis of these folders and of every folder inside them."""
    keys = [os.path.abspath(p) for p in paths]
    for row in session.scalars(select(SourceFolder)).all():
        if any(row.path == k or row.path.startswith(k.rstrip(os.sep) + os.sep) for k in keys):
            session.delete(row)
    session.commit()


def folder_axes(session: Session) -> list[tuple[str, str]]:
    """(folder, up axis) of every remembered folder, the deepest first."""
    rows = session.scalars(select(SourceFolder).where(SourceFolder.up_axis.is_not(None))).all()
    return sorted(((r.path, str(r.up_axis)) for r in rows), key=lambda t: -len(t[0]))


def _stated_for(model: Path, axes: list[tuple[str, str]]) -> tuple[str, str] | None:
    """The remembered (path, axis) that covers ``model``: the model file itself or a folder above it."""
    where = os.path.abspath(model)
    for folder, axis in axes:
        if where == folder or where.startswith(folder.rstrip(os.sep) + os.sep):
            return folder, axis
    return None


def choose_up_axis(cand: Candidate, *, stated_now: str | None, axes: list[tuple[str, str]],
                   assume: str) -> None:
    """Set ``cand.up_axis`` and ``cand.up_reason`` by the rules of the module docstring."""
    if cand.model_path is None or cand.error:
        return
    model = Path(cand.metadata.get("source_model_path") or cand.model_path)
    suffix = model.suffix.lower()
    described = cand.up_reason is not None  # set by the layout from a URDF/SDF (rule 3)
    if cand.up_axis and not described:
        cand.up_reason = cand.up_reason or "stated in the object's metadata"
        return
    folder = _stated_for(model, axes)
    if stated_now:
        cand.up_axis, cand.up_reason = stated_now, "catalog ingest --up-axis"
        return
    if folder is not None:
        cand.up_axis = folder[1]
        cand.up_reason = f"--up-axis {folder[1]} stated earlier for {folder[0]}"
        return
    if described:
        return
    if suffix in GLTF_EXTENSIONS:
        cand.up_axis, cand.up_reason = None, f"glTF specification ({GLTF_UP_AXIS}-up)"
    elif suffix in (".stl", ".step", ".stp"):
        kind = "STL" if suffix == ".stl" else "STEP"
        cand.up_axis, cand.up_reason = "Z", f"{kind}: CAD and 3D-printing tools write Z-up"
    elif suffix in (".obj", ".ply"):
        cand.up_axis, cand.up_reason = None, f"ingest.assume_up_axis ({assume})"
    else:
        cand.up_reason = "stated by the file"
