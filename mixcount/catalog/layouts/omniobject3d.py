"""OmniObject3D (``omniobject3d``): ``<category>/<category>_<NNN>/Scan/Scan.obj`` (+ ``Scan.mtl``,
``Scan.jpg``). Category from the parent folder; units and up axis from ``ingest.omniobject3d_*``."""

from __future__ import annotations

import os
import re
from pathlib import Path

from mixcount.catalog.layouts.candidates import (
    SOURCE_OMNI,
    Candidate,
    Walker,
    is_dir,
    model_files_in,
    preferred_model,
    scan_folder,
)
from mixcount.catalog.naming import category_text, odd_name_reason, safe_text

NAME = SOURCE_OMNI
PRIORITY = 20  # folder layouts are tried in this order


def detect(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> bool:
    return ctx.layout in ("auto", "omniobject3d") and any(e.name == "Scan" and is_dir(e) for e in entries)


def read(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> Candidate:
    """An OmniObject3D object folder: ``Scan/Scan.obj``, category from the parent folder."""
    parent = folder.parent.name
    name = safe_text(folder.name)
    cat_word = parent if folder.name.startswith(parent) and parent else re.sub(r"[_-]?\d+$", "", folder.name)
    cand = Candidate(SOURCE_OMNI, safe_text(f"{parent}/{folder.name}"), name,
                     category_text(cat_word) or "unknown", layout=SOURCE_OMNI)
    reason = odd_name_reason(folder.name)
    if reason:
        cand.error = reason
        return cand
    scan = folder / "Scan"
    try:
        models = model_files_in(scan_folder(scan))
    except OSError as exc:
        cand.error = f"unreadable folder Scan/: {exc.strerror or exc}"
        return cand
    objs = [p for p in models if p.name == "Scan.obj"] or models
    if not objs:
        cand.error = "OmniObject3D folder has no Scan/Scan.obj"
        return cand
    cand.model_path = preferred_model(objs)
    ctx.apply_licence(cand, folder)
    return cand
