"""Plain folders (``folder``): any other model file. A folder with exactly one model file (or a
``metadata.json`` describing one object) is one object: ``metadata.json`` gives name, category, licence,
units and up axis; without it a generic file name (``model.glb``) takes the folder's name. Otherwise each
model file is an object of its own (:func:`read_file`), after the Objaverse reading had its turn."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any, Iterator

from mixcount.catalog.layouts.walker import (
    SOURCE_FOLDER,
    Candidate,
    Walker,
    _preferred,
    apply_identity,
    record_identity,
)
from mixcount.catalog.naming import GENERIC_STEMS, category_from_name, category_from_stem, safe_text

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
    meta_error: str | None = None
    if meta_path.is_file() and ctx.layout != "objaverse":
        try:
            data = json.loads(meta_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            data, meta_error = None, f"metadata.json does not parse: {exc}"
        if data is not None and not isinstance(data, dict):
            meta_error = "metadata.json is not a JSON object"
        elif isinstance(data, dict) and not (data and all(isinstance(v, dict) for v in data.values())):
            record = data  # one object's record (a mapping of many records is side metadata)
    single = models and ctx.layout != "objaverse" and (len(models) == 1 or record is not None or meta_error)
    if single:
        yield _folder_object(ctx, folder, _preferred(models), models, record, meta_error, meta_path)
        return
    for path in models:
        yield ctx.file_object(path)


def _folder_object(ctx: Walker, folder: Path, model: Path, models: list[Path], record: dict[str, Any] | None,
                   meta_error: str | None, meta_path: Path) -> Candidate:
    cand = ctx.file_object(model)
    if cand.source != SOURCE_FOLDER or cand.error:
        return cand
    if meta_error:
        cand.error = meta_error
        return cand
    generic = re.sub(r"[\d_\-\s]+$", "", model.stem).lower() in GENERIC_STEMS
    if generic:
        cand.name = safe_text(folder.name)
        cand.category = category_from_name(folder.name, category_from_stem(folder.name, folder.parent.name))
    if len(models) > 1:
        cand.metadata["other_model_files"] = sorted(p.name for p in models if p != model)
    if record is not None:
        cand.sidecars["metadata.json"] = meta_path
        cand.metadata.update(record)
        ident = record_identity(record)
        apply_identity(cand, ident)
        if ident["license"]:
            cand.license = ident["license"]
    ctx.apply_licence(cand, folder)
    return cand
