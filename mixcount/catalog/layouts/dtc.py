"""Digital Twin Catalog (``dtc``): a folder holding ``3d-asset.*``, or named ``Category_ID_Variant``
with no sub-folders; category from ``metadata.json`` or the folder name. A DTC folder without
``3d-asset.glb`` uses another model file in it when there is one."""

from __future__ import annotations

import os
from pathlib import Path

from mixcount.catalog.layouts.candidates import (
    SOURCE_DTC,
    Candidate,
    Walker,
    is_dir,
    json_object,
    licence_file_in,
    model_files_in,
    preferred_model,
    read_licence_into,
    record_identity,
)
from mixcount.catalog.mesh import MESH_EXTENSIONS
from mixcount.catalog.naming import (
    DTC_NAME,
    category_from_dtc_name,
    category_text,
    odd_name_reason,
    safe_text,
    singular,
)

NAME = SOURCE_DTC
PRIORITY = 30  # folder layouts are tried in this order
DTC_MODEL = "3d-asset"


def detect(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> bool:
    """A ``3d-asset.*`` model, or a ``Category_ID_Variant`` folder without sub-folders (forced ``dtc``:
    any folder without sub-folders holding a model file or ``metadata.json``)."""
    lay = ctx.layout
    if lay not in ("auto", "dtc"):
        return False
    names = {e.name for e in entries}
    dirs = {e.name for e in entries if is_dir(e)}
    if any(Path(n).stem == DTC_MODEL and Path(n).suffix.lower() in MESH_EXTENSIONS for n in names):
        return True
    if DTC_NAME.match(folder.name) and not dirs:
        return True
    return lay == "dtc" and not dirs and ("metadata.json" in names or bool(model_files_in(entries)))


def read(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> Candidate:
    """A DTC object folder: ``3d-asset.*`` (or another model file), identity from ``metadata.json``."""
    name = folder.name
    source_id = safe_text(name)
    match = DTC_NAME.match(name)
    category = singular(match.group("category")) if match else category_from_dtc_name(name, folder.parent.name)
    cand = Candidate(SOURCE_DTC, source_id, source_id, category, layout=SOURCE_DTC)
    reason = odd_name_reason(name)
    if reason:
        cand.error = reason
        return cand
    models = model_files_in(entries)
    own = [p for p in models if p.stem == DTC_MODEL]
    cand.model_path = preferred_model(own) if own else (preferred_model(models) if models else None)
    if cand.model_path is None:
        cand.error = f"DTC folder has no {DTC_MODEL}.glb (and no other model file)"
        return cand
    if not own:
        cand.metadata["model_file"] = cand.model_path.name  # another model file stood in for 3d-asset.glb
    meta = folder / "metadata.json"
    if meta.is_file():
        data = json_object(meta, cand)  # one that does not parse or leads outside: a warning, not read
        if data is not None:
            cand.sidecars["metadata.json"] = meta
            cand.metadata.update(data)
            ident = record_identity(data)
            if ident["category"]:
                cand.category = category_text(ident["category"])
            cand.units, cand.up_axis = ident["units"], ident["up_axis"]
            cand.license = ident["license"]
    lic = licence_file_in(entries)  # a licence file beats a licence field
    if lic is not None:
        read_licence_into(cand, lic)
    ctx.apply_licence(cand, folder)
    return cand
