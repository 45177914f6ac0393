"""Plain folders (``folder``): any other model file. A folder with exactly one model file (companions
aside: ``mug_col.obj``, ``duck_vhacd.obj``, ``chair_lod1.obj``, :mod:`.companions`), or a ``metadata.json``
describing one object, or a URDF/SDF naming one of its meshes, is one object: ``metadata.json`` gives
name, category, licence, units and up axis; without it the object takes the folder's name (the name a
person wrote: ``red_mug/mug.obj`` is "red_mug", category mug), except in the folder given to ingest itself
when it holds neither companions nor a URDF/SDF, and in folders whose name sorts files (``models/``, ``meshes/``: ``GENERIC_FOLDERS``), where only a
generic file name (``model.glb``) takes the folder's name. A URDF/SDF beside the model gives
its scale (units) and up axis; an MJCF also places the parts of a multi-part object. Several model files
that are the parts of one object are one object (:mod:`.parts`: the rule, ``--parts``, a ``parts`` entry),
the same stem in several formats one model. Otherwise each model file is an object of its own
(:func:`read_file`), after the Objaverse reading had its turn."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Iterator

import numpy as np

import mixcount.json_input as json_input
from mixcount.catalog.layouts.candidates import (
    MODEL_PREFERENCE,
    SOURCE_FOLDER,
    Candidate,
    Walker,
    apply_identity,
    ignored_entries,
    preferred_model,
    record_identity,
)
from mixcount.catalog.layouts.companions import RobotDescription, companion_base, companion_kind, descriptions_in
from mixcount.catalog.layouts.parts import auto_parts, check_parts, same_model_formats
from mixcount.catalog.naming import GENERIC_FOLDERS, GENERIC_STEMS, category_from_name, category_from_stem, safe_text
from mixcount.errors import IngestError
from mixcount.library_root import refusal

NAME = SOURCE_FOLDER


def read_file(ctx: Walker, path: Path) -> Candidate:
    """A model file as an object of its own: named after the file, categorised by its stem and folder."""
    stem = safe_text(path.stem)
    return Candidate(SOURCE_FOLDER, safe_text(str(path)), stem, category_from_stem(stem, safe_text(path.parent.name)),
                     path)


def read_models(ctx: Walker, folder: Path, entries: list[os.DirEntry], models: list[Path]) -> Iterator[Candidate]:
    """Model files of a folder that is not a DTC/GSO/OmniObject3D object."""
    meta_path = folder / "metadata.json"
    record: dict[str, Any] | None = None
    # a metadata.json that does not parse, is no object or leads outside the library: a warning on the
    # folder's objects (said with the reason), which are ingested without it
    meta_note: str | None = None
    if meta_path.is_file() and ctx.layout != "objaverse":
        outside = refusal(meta_path, "metadata.json")
        try:
            data = None if outside else json_input.read(meta_path)  # too deep / too large: one line
        except (OSError, ValueError) as exc:
            data, meta_note = None, f"metadata.json does not parse, not used: {exc}"
        if outside:
            meta_note = f"metadata.json not read: {outside}"
        elif data is not None and not isinstance(data, dict):
            meta_note = "metadata.json is not a JSON object, not used"
        elif isinstance(data, dict) and not (data and all(isinstance(v, dict) for v in data.values())):
            record = data  # one object's record (a mapping of many records is side metadata)
    if ctx.layout == "objaverse":
        for path in models:
            yield ctx.file_object(path)
        return
    files = [Path(e.path) for e in entries]
    unread: list[str] = []  # descriptions that do not parse: a warning on the folder's objects
    descriptions = descriptions_in(files, unread)
    if not descriptions and record is None and folder != ctx.root and folder.name.strip().lower() in GENERIC_FOLDERS:
        above = _description_above(folder, unread)  # Toy car/toy_car.xml beside Toy car/meshes/ (an MJCF meshdir)
        if above:
            descriptions, folder = above, folder.parent
    if unread:
        meta_note = "; ".join(([meta_note] if meta_note else []) + unread)
    main, companions = split_companions(models, descriptions)
    main, copies = same_model_formats(main, MODEL_PREFERENCE)
    stated = record.get("parts") if record is not None else None
    try:  # "parts": 3 (a count of parts, as several datasets write it) is no rule: ignored, said once
        rule = check_parts(stated if isinstance(stated, str) else getattr(ctx, "parts", "auto"))
    except IngestError:
        rule = check_parts(getattr(ctx, "parts", "auto"))
    described = [d for d in descriptions if d.visual and any(m.name == d.visual for m in main)]
    parts, why = _parts_of(ctx, folder, main, described, rule, record is not None)
    if parts:
        desc = next((d for d in described if d.parts), described[0] if described else None)
        first = parts[0][0]
        yield _folder_object(ctx, folder, first, models, record, meta_note, meta_path, companions, desc,
                             parts=parts, parts_rule=why, copies=copies)
        return
    if len(main) > 1 and len(described) == 1 and record is None:
        main = [m for m in main if m.name == described[0].visual]  # the URDF names the model
    if len(main) == 1 or (record is not None and rule != "separate"):
        model = main[0] if len(main) == 1 else preferred_model(main)
        desc = next((d for d in described if d.visual == model.name), None)
        yield _folder_object(ctx, folder, model, models, record, meta_note, meta_path, companions, desc,
                             parts_rule=why, copies=copies)
        return
    for path in main:
        cand = ctx.file_object(path)
        if meta_note and not cand.error:
            cand.warnings.append(meta_note)
        own = {k: v for k, v in companions.items() if companion_base(v.stem) == path.stem}
        _attach(cand, own, next((d for d in described if d.visual == path.name), None))
        if why:
            cand.parts_rule = why
        yield cand


def _description_above(folder: Path, notes: list[str]) -> list[RobotDescription]:
    """The descriptions (URDF/SDF/MJCF) in the folder above a generic mesh folder (``meshes/``)."""
    try:
        files = sorted(p for p in folder.parent.iterdir() if p.is_file() and not refusal(p, p.name))
    except OSError:
        return []
    return descriptions_in(files, notes)


def _parts_of(ctx: Walker, folder: Path, main: list[Path], described: list[RobotDescription], rule: str,
              has_record: bool) -> tuple[list[tuple[Path, Any]], str | None]:
    """(the parts of the folder's one object, placed; why) by the rule of :mod:`.parts`, or ([], why)
    when its model files are separate models (why None when there was nothing to decide)."""
    if len(main) < 2 or rule == "separate":
        return [], ("separate models: stated (parts: separate)" if rule == "separate" and len(main) > 1 else None)
    by_name = {m.name: m for m in main}
    placed = next((d for d in described if len(d.parts) >= 2), None)
    if placed is not None:
        scale = placed.mesh_scale[0] if placed.units() is not None else 1.0
        parts = []
        for name, matrix in placed.parts:
            if name in by_name:
                local = np.array(matrix, dtype=np.float64)
                local[:3, 3] /= scale  # the description places parts in metres; the meshes are in its units
                parts.append((by_name[name], local))
        if len(parts) >= 2:
            return parts, f"parts of one object: {placed.kind} {placed.path.name} places {len(parts)} visual meshes in one body"
    if rule == "merge":
        return [(m, None) for m in main], "parts of one object: stated (parts: merge)"
    if has_record or folder == ctx.root or len(described) == 1:
        return [], None
    ok, why = auto_parts(folder, main)
    return ([(m, None) for m in main], why) if ok else ([], why)


def split_companions(models: list[Path], descriptions: list[RobotDescription]) -> tuple[list[Path], dict[str, Path]]:
    """(model files, companions by ``kind:file name``) of one folder: a file is a companion when its stem
    says so (or a URDF/SDF uses it as collision mesh only) and another model file is left as the object."""
    collision_only = ({c for d in descriptions for c in (d.collision_files or (d.collision,)) if c}
                      - {d.visual for d in descriptions} - {f for d in descriptions for f, _m in d.parts})
    kinds = {m: ("collision" if m.name in collision_only else companion_kind(m.stem)) for m in models}
    main = [m for m in models if kinds[m] is None]
    if not main:
        return list(models), {}
    return main, {f"{kinds[m]}:{m.name}": m for m in models if kinds[m] is not None}


def _attach(cand: Candidate, companions: dict[str, Path], desc: RobotDescription | None) -> None:
    """Companions and what a URDF/SDF says, onto a candidate (its units/up axis unless stated)."""
    if cand.source != SOURCE_FOLDER or cand.error:
        return
    cand.companions.update(companions)
    collision = sorted(p for k, p in companions.items() if k.startswith("collision:"))
    if desc is not None and desc.collision:
        named = [p for p in collision if p.name == desc.collision]
        collision = named or collision
    if collision:
        cand.collision_source = collision[0]
    if desc is None:
        return
    cand.sidecars[f"description:{desc.path.name}"] = desc.path
    cand.metadata["description"] = {"file": desc.path.name, "name": desc.name, "scale": list(desc.mesh_scale)}
    if desc.colours:
        cand.colours.update(desc.colours)
        cand.metadata["description"]["colours"] = {name: list(rgba) for name, rgba in sorted(desc.colours.items())}
    cand.warnings.extend(desc.warnings)
    units = desc.units()
    if units is not None and not cand.units:
        cand.units = units
        cand.units_reason = (f"description: {desc.kind or 'the'} {desc.path.name} gives the mesh scale "
                             f"{desc.mesh_scale[0]:g} (" + ("metres" if units == "m" else f"{units} m per unit") + ")")
    if desc.up_axis and not cand.up_axis:
        cand.up_axis = desc.up_axis
        kind = desc.kind or desc.path.suffix.lstrip('.').upper()
        cand.up_reason = f"{kind} {desc.path.name} beside the model (Z-up body" + (
            ")" if desc.up_axis == "Z" else f", mesh turned so that its {desc.up_axis} points up)")


def _folder_object(ctx: Walker, folder: Path, model: Path, models: list[Path], record: dict[str, Any] | None,
                   meta_note: str | None, meta_path: Path, companions: dict[str, Path],
                   desc: RobotDescription | None, *, parts: list[tuple[Path, Any]] | None = None,
                   parts_rule: str | None = None, copies: list[Path] | None = None) -> Candidate:
    cand = ctx.file_object(model)
    if cand.source != SOURCE_FOLDER or cand.error:
        return cand
    cand.parts, cand.parts_rule = list(parts or []), parts_rule
    if copies:
        cand.metadata["other_formats"] = sorted(p.name for p in copies)
    if meta_note:
        cand.warnings.append(meta_note)
    generic = re.sub(r"[\d_\-\s]+$", "", model.stem).lower() in GENERIC_STEMS
    # the folder given to ingest names its model only when it is clearly one object's folder (it holds
    # companions or a URDF/SDF): a folder of loose files keeps its files' names
    named_folder = folder != ctx.root or bool(companions) or desc is not None or bool(parts)
    if generic or (named_folder and folder.name.strip().lower() not in GENERIC_FOLDERS):
        cand.name = safe_text(folder.name)
        cand.category = category_from_name(folder.name, category_from_stem(folder.name, folder.parent.name))
    elif desc is not None and desc.name:
        cand.name = safe_text(desc.name)
        cand.category = category_from_stem(desc.name, cand.category)
    in_parts = {p for p, _m in cand.parts}
    others = [p for p in models if p != model and p not in companions.values() and p not in in_parts
              and p not in (copies or [])]
    if cand.parts:
        cand.metadata["parts"] = [p.name for p, _m in cand.parts]
    if others:
        cand.metadata["other_model_files"] = sorted(p.name for p in others)
    if companions:
        cand.metadata["companions"] = sorted(companions)
    if record is not None:
        cand.sidecars["metadata.json"] = meta_path
        # the record's own "parts" (a rule, or a count as several datasets write it) is kept as
        # "parts_stated": "parts" is the catalog's list of the object's part files (catalog show / list)
        cand.metadata.update({("parts_stated" if k == "parts" else k): v for k, v in record.items()})
        cand.ignored.extend(ignored_entries(record))
        ident = record_identity(record)
        apply_identity(cand, ident)
        if ident["license"]:
            cand.license = ident["license"]
    _attach(cand, companions, desc)
    ctx.apply_licence(cand, folder)
    return cand
