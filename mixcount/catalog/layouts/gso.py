"""Google Scanned Objects (``gso``): a folder with ``meshes/model.obj`` next to ``metadata.pbtxt``,
``model.sdf`` or ``model.config``. Name, category and licence from ``metadata.pbtxt`` (protobuf text
format); metres, Z-up (Gazebo/SDF). The ``model.mtl`` names ``texture.png``, which ships in
``materials/textures/``: the object is *staged* (the OBJ, its MTL and the texture linked side by side)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from mixcount.catalog.layouts.candidates import (
    SOURCE_GSO,
    Candidate,
    Walker,
    is_dir,
    model_files_in,
    preferred_model,
    scan_folder,
)
from mixcount.catalog.naming import category_from_name, category_text, odd_name_reason, safe_text
from mixcount.library_root import refusal

NAME = SOURCE_GSO
PRIORITY = 10  # folder layouts are tried in this order
GSO_MARKERS = ("metadata.pbtxt", "model.sdf", "model.config")


def detect(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> bool:
    """A ``meshes/`` folder beside a GSO marker file (forced ``gso``: either one)."""
    names = {e.name for e in entries}
    dirs = {e.name for e in entries if is_dir(e)}
    lay = ctx.layout
    if lay in ("auto", "gso") and "meshes" in dirs and (lay == "gso" or names & set(GSO_MARKERS)):
        return True
    return lay == "gso" and bool(names & set(GSO_MARKERS))


def read(ctx: Walker, folder: Path, entries: list[os.DirEntry]) -> Candidate:
    """A GSO object folder: ``meshes/model.obj``, identity from ``metadata.pbtxt``, textures staged."""
    name = safe_text(folder.name)
    cand = Candidate(SOURCE_GSO, name, name, category_from_name(name), layout=SOURCE_GSO, units="m", up_axis="Z")
    reason = odd_name_reason(folder.name)
    if reason:
        cand.error = reason
        return cand
    meshes = folder / "meshes"
    try:
        models = model_files_in(scan_folder(meshes)) if meshes.is_dir() else []
    except OSError as exc:
        cand.error = f"unreadable folder meshes/: {exc.strerror or exc}"
        return cand
    objs = [p for p in models if p.name == "model.obj"] or [p for p in models if p.suffix.lower() == ".obj"]
    cand.model_path = objs[0] if objs else (preferred_model(models) if models else None)
    pbtxt = folder / "metadata.pbtxt"
    outside = refusal(pbtxt, "metadata.pbtxt") if pbtxt.is_file() else None
    if outside:
        cand.warnings.append(f"metadata.pbtxt not read: {outside}")
    elif pbtxt.is_file():
        try:
            ident = gso_identity(parse_pbtxt(pbtxt.read_text(encoding="utf-8", errors="replace")))
        except (OSError, ValueError) as exc:  # a warning on the object, which keeps the folder's name
            ident = {"name": None, "category": None, "license": None}
            cand.warnings.append(f"metadata.pbtxt does not parse, not used: {str(exc)[:200]}")
        else:
            cand.sidecars["metadata.pbtxt"] = pbtxt
        if ident["name"]:
            cand.name = safe_text(ident["name"])
        cand.category = category_text(ident["category"]) if ident["category"] else category_from_name(cand.name)
        cand.license = ident["license"]
        cand.metadata.update({k: v for k, v in ident.items() if v})
    for marker in ("model.config", "model.sdf"):
        if (folder / marker).is_file() and not refusal(folder / marker, marker):
            cand.sidecars[marker] = folder / marker
    if cand.model_path is None:
        cand.error = "GSO folder has no meshes/model.obj"
        return cand
    if cand.model_path.suffix.lower() == ".obj":
        _stage_textures(cand, folder)
    ctx.apply_licence(cand, folder)
    return cand


def _stage_textures(cand: Candidate, folder: Path) -> None:
    """GSO's MTL names ``texture.png`` beside it; the file is in ``materials/textures/``."""
    assert cand.model_path is not None
    mtls, textures = _obj_textures(cand.model_path)
    missing = [t for t in textures if not (cand.model_path.parent / t).is_file()]
    if not missing:
        return
    staged = {cand.model_path.name: cand.model_path, **{m.name: m for m in mtls}}
    for tex in textures:
        here = cand.model_path.parent / tex
        there = folder / "materials" / "textures" / Path(tex).name
        if here.is_file():
            staged[tex] = here
        elif there.is_file() and "/" not in tex.replace("\\", "/"):
            staged[tex] = there
        else:
            return  # a texture missing everywhere: the ingest pre-check reports it
    cand.staged = staged


def parse_pbtxt(text: str) -> dict[str, list[Any]]:
    """Protobuf text format (``metadata.pbtxt``) as nested dicts of field -> list of values.

    Handles what Gazebo Fuel metadata uses: ``field: "string"``, numbers and identifiers, nested
    messages ``field { ... }`` (with or without a colon) and comments. Map entries come out as
    messages with ``key``/``value`` fields. Raises ValueError on malformed input."""
    tokens = re.findall(r'"(?:[^"\\]|\\.)*"|\'(?:[^\'\\]|\\.)*\'|#[^\n]*|[{}:;,\[\]<>]|[^\s{}:;,\[\]<>"\']+', text)
    tokens = [t for t in tokens if not t.startswith("#")]
    pos = 0

    def value(tok: str) -> Any:
        if tok[:1] in "\"'":
            return bytes(tok[1:-1], "utf-8").decode("unicode_escape").encode("latin-1").decode("utf-8", "replace")
        try:
            return int(tok)
        except ValueError:
            try:
                return float(tok)
            except ValueError:
                return tok

    def message(closing: str | None) -> dict[str, list[Any]]:
        nonlocal pos
        out: dict[str, list[Any]] = {}
        while pos < len(tokens):
            tok = tokens[pos]
            if tok in ("}", ">"):
                if closing is None:
                    raise ValueError("unbalanced '}'")
                pos += 1
                return out
            if tok in (";", ","):
                pos += 1
                continue
            key = tok
            pos += 1
            if pos < len(tokens) and tokens[pos] == ":":
                pos += 1
            if pos >= len(tokens):
                raise ValueError(f"field {key!r} has no value")
            if tokens[pos] in ("{", "<"):
                pos += 1
                out.setdefault(key, []).append(message(tokens[pos - 1]))
                continue
            if tokens[pos] == "[":  # repeated scalars: [a, b]
                pos += 1
                while pos < len(tokens) and tokens[pos] != "]":
                    if tokens[pos] != ",":
                        out.setdefault(key, []).append(value(tokens[pos]))
                    pos += 1
                pos += 1
                continue
            parts = [tokens[pos]]
            pos += 1
            while parts[0][:1] in "\"'" and pos < len(tokens) and tokens[pos][:1] in "\"'":  # "a" "b" concatenation
                parts.append(tokens[pos])
                pos += 1
            out.setdefault(key, []).append("".join(str(value(p)) for p in parts) if len(parts) > 1 else value(parts[0]))
        if closing is not None:
            raise ValueError("unterminated message")
        return out

    return message(None)


def gso_identity(doc: dict[str, list[Any]]) -> dict[str, Any]:
    """name, description, category and licence of a parsed GSO ``metadata.pbtxt``."""

    def scalar(d: dict[str, list[Any]], key: str) -> str | None:
        vals = [v for v in d.get(key, []) if isinstance(v, (str, int, float))]
        return str(vals[0]).strip() or None if vals else None

    categories = [str(v).strip() for v in doc.get("categories", []) if isinstance(v, (str, int, float))]
    annotations = {}
    for entry in doc.get("annotations", []):
        if isinstance(entry, dict):
            k, v = scalar(entry, "key"), scalar(entry, "value")
            if k and v:
                annotations[k] = v
    if annotations.get("category"):
        categories.append(annotations["category"])
    categories = [c for c in categories if c and c.lower() not in ("none", "null", "unknown")]
    lic = scalar(doc, "license")
    for legal in doc.get("legal", []):
        if isinstance(legal, dict):
            lic = lic or scalar(legal, "license")
    return {"name": scalar(doc, "name"), "description": scalar(doc, "description"),
            "category": categories[0] if categories else None, "license": lic,
            "tags": [str(t) for t in doc.get("tags", []) if isinstance(t, str)], "annotations": annotations}


_MTL_MAP = re.compile(r"^\s*(map_\w+|bump|disp|decal|norm)\s+(.+?)\s*$", re.IGNORECASE)


def _obj_textures(obj: Path) -> tuple[list[Path], list[str]]:
    """The MTL files an OBJ names (existing ones) and the texture names those MTLs reference."""
    mtls, textures = [], []
    try:
        for line in obj.read_text(errors="replace").splitlines():
            if line.startswith("mtllib"):
                name = line[len("mtllib"):].strip()
                if name and (obj.parent / name).is_file():
                    mtls.append(obj.parent / name)
    except OSError:
        return [], []
    for mtl in mtls:
        try:
            for mline in mtl.read_text(errors="replace").splitlines():
                match = _MTL_MAP.match(mline)
                if match:
                    textures.append(match.group(2).split()[-1])
        except OSError:
            continue
    return mtls, textures
