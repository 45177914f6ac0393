"""Library layouts: find every object under a path, with the name, category and licence its layout gives.

``discover(paths, layout="auto")`` walks each path and returns one :class:`Candidate` per object. In
``auto`` mode each folder is recognised on its own, so a tree may mix layouts (docs/ingest.md):

* **Google Scanned Objects** (``gso``): a folder with ``meshes/model.obj`` next to ``metadata.pbtxt``,
  ``model.sdf`` or ``model.config``. Name, category and licence from ``metadata.pbtxt`` (protobuf text
  format); metres, Z-up (Gazebo/SDF). The ``model.mtl`` names ``texture.png``, which ships in
  ``materials/textures/``: the object is *staged* (the OBJ, its MTL and the texture linked side by side
  under the catalog's data folder), so every loader finds the texture without touching the library.
* **OmniObject3D** (``omniobject3d``): ``<category>/<category>_<NNN>/Scan/Scan.obj`` (+ ``Scan.mtl``,
  ``Scan.jpg``). Category from the parent folder; units and up axis from ``ingest.omniobject3d_*``.
* **Digital Twin Catalog** (``dtc``): a folder holding ``3d-asset.*``, or named
  ``Category_ID_Variant`` with no sub-folders; category from ``metadata.json`` or the folder name. A DTC
  folder without ``3d-asset.glb`` uses another model file in it when there is one.
* **Objaverse / Amazon Berkeley Objects** (``objaverse``): trees of model files named by an id (uid,
  ``3dmodel_id``), described by side metadata files (JSON mapping or list, JSONL, CSV; ``.gz`` too) in
  the folders above the model, in ``metadata/`` or ``annotations/`` beside them (Objaverse's
  ``glbs/`` + ``metadata/``), or given with ``--metadata`` (ABO's ``listings/metadata/*.json.gz``).
  A model whose file stem is an id in those files takes its name, category and licence from the record.
* **Plain folders** (``folder``): any other model file. A folder with exactly one model file (or a
  ``metadata.json`` describing one object) is one object: ``metadata.json`` gives name, category,
  licence, units and up axis; without it a generic file name (``model.glb``) takes the folder's name.

Every object without a licence of its own takes the nearest ``LICENSE``/``LICENCE``/``COPYING`` file in
its folder or the folders above it (up to the path given). ``layout`` other than ``auto`` forces one
reading: folders that look like an object of that layout but lack its model become broken objects with a
layout-specific reason, and other layouts' folder rules are not applied.
"""

from __future__ import annotations

import csv
import gzip
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

from mixcount.catalog.mesh import MESH_EXTENSIONS
from mixcount.catalog.naming import (
    DTC_NAME,
    GENERIC_STEMS,
    category_from_name,
    category_from_stem,
    category_text,
    odd_name_reason,
    safe_text,
    singular,
)
from mixcount.errors import CatalogError

LAYOUTS = ("auto", "dtc", "gso", "objaverse", "omniobject3d", "folder")
SOURCE_DTC = "dtc"
SOURCE_GSO = "gso"
SOURCE_OBJAVERSE = "objaverse"
SOURCE_OMNI = "omniobject3d"
SOURCE_FOLDER = "folder"
DTC_MODEL = "3d-asset"
# LICENSE, LICENCE.txt, COPYING, LICENSE-CC-BY-NC-4.0.txt (Amazon Berkeley Objects), license.md ...
LICENCE_NAMES = re.compile(r"^(licen[cs]e|copying)([-_.][\w.-]*)?$", re.IGNORECASE)
MODEL_PREFERENCE = (".glb", ".gltf", ".usdz", ".usd", ".usdc", ".usda", ".obj", ".ply", ".stl")
SIDE_SUFFIXES = (".json", ".jsonl", ".csv", ".json.gz", ".jsonl.gz", ".csv.gz")
SIDE_FOLDERS = ("metadata", "annotations")
GSO_MARKERS = ("metadata.pbtxt", "model.sdf", "model.config")
ID_FIELDS = ("uid", "id", "object_id", "model_id", "3dmodel_id", "item_id", "sha256", "file_identifier", "asset_id")
NAME_FIELDS = ("name", "title", "item_name", "display_name", "object_name")
CATEGORY_FIELDS = ("category", "class", "label", "lvis_category", "categories", "product_type", "super_category")
LICENCE_FIELDS = ("license", "licence", "license_name", "licenseName", "license_url")
# Sketchfab licence slugs as Objaverse's annotations carry them.
LICENCE_SLUGS = {
    "by": "CC BY 4.0", "by-sa": "CC BY-SA 4.0", "by-nd": "CC BY-ND 4.0", "by-nc": "CC BY-NC 4.0",
    "by-nc-sa": "CC BY-NC-SA 4.0", "by-nc-nd": "CC BY-NC-ND 4.0", "cc0": "CC0 1.0",
}
LICENCE_CHARS = 4000


@dataclass
class Candidate:
    """One object found on disk, before hashing."""

    source: str
    source_id: str
    name: str
    category: str
    model_path: Path | None = None
    sidecars: dict[str, Path] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    license: str | None = None
    units: str | None = None
    up_axis: str | None = None
    error: str | None = None  # a problem found during discovery: the object is broken
    layout: str = SOURCE_FOLDER
    # files a model loader must find side by side (reference name -> real file); ingest links them
    # into one folder under the catalog's data folder and analyses, renders and converts that copy
    staged: dict[str, Path] = field(default_factory=dict)


# --------------------------------------------------------------------------- small readers


def _model_files(entries: list[os.DirEntry]) -> list[Path]:
    out = []
    for e in entries:
        if e.name.startswith(".") or Path(e.name).suffix.lower() not in MESH_EXTENSIONS:
            continue
        try:
            if e.is_file():
                out.append(Path(e.path))
        except OSError:
            continue
    return out


def _preferred(files: list[Path]) -> Path:
    """The main model among several files of one object: GLB first, STL last, then by name."""
    return min(files, key=lambda p: (MODEL_PREFERENCE.index(p.suffix.lower()), p.name))


def _scan(folder: Path) -> list[os.DirEntry]:
    return sorted(os.scandir(folder), key=lambda e: e.name)


def _is_dir(entry: os.DirEntry) -> bool:
    try:
        return entry.is_dir()
    except OSError:
        return False


def _text(value: Any) -> str | None:
    """A display string from a metadata value: str, number, {value|name|label}, or a list of them
    (language-tagged lists such as ABO's ``item_name`` prefer English)."""
    if isinstance(value, str):
        return value.strip() or None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return str(value)
    if isinstance(value, dict):
        for key in ("value", "name", "label", "title"):
            if key in value:
                return _text(value[key])
        return None
    if isinstance(value, list) and value:
        english = [v for v in value if isinstance(v, dict) and str(v.get("language_tag", "")).startswith("en")]
        for item in english + list(value):
            text = _text(item)
            if text:
                return text
    return None


def _first(record: dict[str, Any], keys: tuple[str, ...]) -> str | None:
    for key in keys:
        if key in record:
            text = _text(record[key])
            if text:
                return text
    return None


def record_identity(record: dict[str, Any]) -> dict[str, str | None]:
    """name, category, licence, units, up axis from a metadata record (any of the usual field names)."""
    lic = _first(record, LICENCE_FIELDS)
    if lic is not None:
        lic = LICENCE_SLUGS.get(lic.strip().lower(), lic)
    category = _first(record, CATEGORY_FIELDS)
    if category is not None and category.strip().lower() in ("none", "null", "unknown", "other", ""):
        category = None
    units = record.get("units") if isinstance(record.get("units"), str) else None
    up = record.get("up_axis") if isinstance(record.get("up_axis"), str) else None
    return {"name": _first(record, NAME_FIELDS), "category": category, "license": lic, "units": units, "up_axis": up}


def _read_licence(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace")[:LICENCE_CHARS].strip()


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


# --------------------------------------------------------------------------- side metadata


class SideMetadata:
    """Records of JSON / JSONL / CSV side files, indexed by every id-like field (and mapping key).

    Files are read once, when a model first needs them; a file that does not parse as records is
    skipped (it is not side metadata). ``explicit`` files are searched for every model."""

    def __init__(self, explicit: Iterable[Path] = ()) -> None:
        self._loaded: dict[Path, dict[str, dict[str, Any]]] = {}
        self._dir_files: dict[Path, list[Path]] = {}
        self._side_dirs: dict[Path, list[Path]] = {}
        self.explicit = [Path(p).expanduser().resolve() for p in explicit]
        for p in self.explicit:
            if not p.is_file():
                raise CatalogError(f"metadata file not found: {p}")
            if not self._index(p):
                raise CatalogError(f"metadata file {p} holds no records (JSON object or list, JSONL or CSV "
                                   "with an id column such as uid)")

    @staticmethod
    def _records(path: Path) -> Iterator[tuple[str | None, dict[str, Any]]]:
        name = path.name.lower()
        opener = gzip.open if name.endswith(".gz") else open
        base = name[:-3] if name.endswith(".gz") else name
        with opener(path, "rt", encoding="utf-8", errors="replace", newline="") as fh:  # type: ignore[operator]
            if base.endswith(".csv"):
                for row in csv.DictReader(fh):
                    yield None, {k.strip(): v for k, v in row.items() if k}
                return
            text = fh.read()
        try:
            data = None if base.endswith(".jsonl") else json.loads(text)
        except ValueError:
            data = None  # ABO names its JSON-lines listings *.json.gz
        if data is None:
            for line in text.splitlines():
                line = line.strip()
                if line:
                    rec = json.loads(line)
                    if isinstance(rec, dict):
                        yield None, rec
            return
        if isinstance(data, list):
            for rec in data:
                if isinstance(rec, dict):
                    yield None, rec
        elif isinstance(data, dict) and data and all(isinstance(v, dict) for v in data.values()):
            for key, rec in data.items():
                yield str(key), rec

    def _index(self, path: Path) -> dict[str, dict[str, Any]]:
        if path in self._loaded:
            return self._loaded[path]
        index: dict[str, dict[str, Any]] = {}
        try:
            for key, rec in self._records(path):
                keys = {key} if key else set()
                for f in ID_FIELDS:
                    v = rec.get(f)
                    if isinstance(v, (str, int)) and not isinstance(v, bool) and str(v).strip():
                        keys.add(str(v).strip())
                for f in ("path", "file", "filename", "glb", "model"):
                    v = rec.get(f)
                    if isinstance(v, str) and v.strip():
                        keys.add(Path(v.strip()).stem)
                for k in keys:
                    index.setdefault(k, rec)
        except (OSError, ValueError, UnicodeDecodeError, csv.Error, EOFError):
            index = {}
        self._loaded[path] = index
        return index

    def _side_files(self, folder: Path) -> list[Path]:
        if folder not in self._dir_files:
            files = []
            try:
                for e in _scan(folder):
                    if e.name.startswith(".") or e.name == "metadata.json" and _has_single_model(folder):
                        continue
                    if e.name.lower().endswith(SIDE_SUFFIXES) and e.is_file():
                        files.append(Path(e.path))
            except OSError:
                pass
            self._dir_files[folder] = files
        return self._dir_files[folder]

    def _with_side_folders(self, folder: Path) -> list[Path]:
        if folder not in self._side_dirs:
            self._side_dirs[folder] = [folder] + [folder / n for n in SIDE_FOLDERS if (folder / n).is_dir()]
        return self._side_dirs[folder]

    def lookup(self, uid: str, folder: Path, root: Path) -> tuple[dict[str, Any], Path] | None:
        """The record for ``uid`` from files in ``folder`` and above (up to ``root``), in a ``metadata/``
        or ``annotations/`` folder beside any of those, or in the explicit files; with its file."""
        dirs = []
        cur = folder
        while True:
            dirs.append(cur)
            if cur == root or cur.parent == cur or root not in cur.parents:
                break
            cur = cur.parent
        files = list(self.explicit) + [f for d in dirs for side in self._with_side_folders(d) for f in self._side_files(side)]
        for path in files:
            rec = self._index(path).get(uid)
            if rec is not None:
                return rec, path
        return None


def _has_single_model(folder: Path) -> bool:
    try:
        return len(_model_files(_scan(folder))) == 1
    except OSError:
        return False


# --------------------------------------------------------------------------- the walk


class _Walker:
    """Walks one root path and yields candidates (see the module docstring for the rules)."""

    def __init__(self, root: Path, layout: str, side: SideMetadata) -> None:
        self.root = root
        self.layout = layout
        self.side = side
        self._licences: dict[Path, tuple[str, Path] | None] = {}

    # licences --------------------------------------------------------------------------------
    def _folder_licence(self, folder: Path) -> tuple[str, Path] | None:
        if folder not in self._licences:
            found = None
            try:
                for e in _scan(folder):
                    if LICENCE_NAMES.match(e.name) and e.is_file():
                        found = (_read_licence(Path(e.path)), Path(e.path))
                        break
            except OSError:
                pass
            self._licences[folder] = found
        return self._licences[folder]

    def inherited_licence(self, folder: Path) -> tuple[str, Path] | None:
        """The nearest licence file in ``folder`` or above it, up to the root (and the root's parent
        when the root is itself an object folder)."""
        cur = folder
        top = self.root if self.root != folder else self.root.parent
        while True:
            lic = self._folder_licence(cur)
            if lic is not None:
                return lic
            if cur == top or cur.parent == cur or (top not in cur.parents):
                return None
            cur = cur.parent

    def _apply_licence(self, cand: Candidate, folder: Path) -> None:
        if cand.license is None:
            lic = self.inherited_licence(folder)
            if lic is not None:
                cand.license = lic[0]
                cand.sidecars.setdefault(f"licence:{lic[1].name}", lic[1])

    # object kinds ----------------------------------------------------------------------------
    def object_kind(self, folder: Path, entries: list[os.DirEntry]) -> str | None:
        names = {e.name for e in entries}
        dirs = {e.name for e in entries if _is_dir(e)}
        lay = self.layout
        if lay in ("auto", "gso") and "meshes" in dirs and (lay == "gso" or names & set(GSO_MARKERS)):
            return SOURCE_GSO
        if lay == "gso" and names & set(GSO_MARKERS):
            return SOURCE_GSO
        if lay in ("auto", "omniobject3d") and "Scan" in dirs:
            return SOURCE_OMNI
        if lay in ("auto", "dtc"):
            if any(Path(n).stem == DTC_MODEL and Path(n).suffix.lower() in MESH_EXTENSIONS for n in names):
                return SOURCE_DTC
            if DTC_NAME.match(folder.name) and not dirs:
                return SOURCE_DTC
            if lay == "dtc" and not dirs and ("metadata.json" in names or _model_files(entries)):
                return SOURCE_DTC
        return None

    # candidates ------------------------------------------------------------------------------
    def dtc(self, folder: Path, entries: list[os.DirEntry]) -> Candidate:
        name = folder.name
        source_id = safe_text(name)
        match = DTC_NAME.match(name)
        category = singular(match.group("category")) if match else category_from_stem(name, folder.parent.name)
        cand = Candidate(SOURCE_DTC, source_id, source_id, category, layout=SOURCE_DTC)
        reason = odd_name_reason(name)
        if reason:
            cand.error = reason
            return cand
        models = _model_files(entries)
        own = [p for p in models if p.stem == DTC_MODEL]
        cand.model_path = _preferred(own) if own else (_preferred(models) if models else None)
        if cand.model_path is None:
            cand.error = f"DTC folder has no {DTC_MODEL}.glb (and no other model file)"
            return cand
        if not own:
            cand.metadata["model_file"] = cand.model_path.name  # another model file stood in for 3d-asset.glb
        meta = folder / "metadata.json"
        if meta.is_file():
            cand.sidecars["metadata.json"] = meta
            data = self._json_object(meta, cand)
            if data is None:
                return cand
            cand.metadata.update(data)
            ident = record_identity(data)
            if ident["category"]:
                cand.category = category_text(ident["category"])
            cand.units, cand.up_axis = ident["units"], ident["up_axis"]
            cand.license = ident["license"]
        lic = _licence_file(entries)  # a licence file beats a licence field
        if lic is not None:
            self._read_licence_into(cand, lic)
        self._apply_licence(cand, folder)
        return cand

    def gso(self, folder: Path, entries: list[os.DirEntry]) -> Candidate:
        name = safe_text(folder.name)
        cand = Candidate(SOURCE_GSO, name, name, category_from_name(name), layout=SOURCE_GSO, units="m", up_axis="Z")
        reason = odd_name_reason(folder.name)
        if reason:
            cand.error = reason
            return cand
        meshes = folder / "meshes"
        try:
            models = _model_files(_scan(meshes)) if meshes.is_dir() else []
        except OSError as exc:
            cand.error = f"unreadable folder meshes/: {exc.strerror or exc}"
            return cand
        objs = [p for p in models if p.name == "model.obj"] or [p for p in models if p.suffix.lower() == ".obj"]
        cand.model_path = objs[0] if objs else (_preferred(models) if models else None)
        pbtxt = folder / "metadata.pbtxt"
        if pbtxt.is_file():
            cand.sidecars["metadata.pbtxt"] = pbtxt
            try:
                ident = gso_identity(parse_pbtxt(pbtxt.read_text(encoding="utf-8", errors="replace")))
            except (OSError, ValueError) as exc:
                cand.error = f"metadata.pbtxt does not parse: {exc}"
                return cand
            if ident["name"]:
                cand.name = safe_text(ident["name"])
            cand.category = category_text(ident["category"]) if ident["category"] else category_from_name(cand.name)
            cand.license = ident["license"]
            cand.metadata.update({k: v for k, v in ident.items() if v})
        for marker in ("model.config", "model.sdf"):
            if (folder / marker).is_file():
                cand.sidecars[marker] = folder / marker
        if cand.model_path is None:
            cand.error = "GSO folder has no meshes/model.obj"
            return cand
        if cand.model_path.suffix.lower() == ".obj":
            self._stage_gso_textures(cand, folder)
        self._apply_licence(cand, folder)
        return cand

    @staticmethod
    def _stage_gso_textures(cand: Candidate, folder: Path) -> None:
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

    def omni(self, folder: Path, entries: list[os.DirEntry]) -> Candidate:
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
            models = _model_files(_scan(scan))
        except OSError as exc:
            cand.error = f"unreadable folder Scan/: {exc.strerror or exc}"
            return cand
        objs = [p for p in models if p.name == "Scan.obj"] or models
        if not objs:
            cand.error = "OmniObject3D folder has no Scan/Scan.obj"
            return cand
        cand.model_path = _preferred(objs)
        self._apply_licence(cand, folder)
        return cand

    def files(self, folder: Path, entries: list[os.DirEntry], models: list[Path]) -> Iterator[Candidate]:
        """Model files of a folder that is not a DTC/GSO/OmniObject3D object."""
        meta_path = folder / "metadata.json"
        record: dict[str, Any] | None = None
        meta_error: str | None = None
        if meta_path.is_file() and self.layout != "objaverse":
            try:
                data = json.loads(meta_path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                data, meta_error = None, f"metadata.json does not parse: {exc}"
            if data is not None and not isinstance(data, dict):
                meta_error = "metadata.json is not a JSON object"
            elif isinstance(data, dict) and not (data and all(isinstance(v, dict) for v in data.values())):
                record = data  # one object's record (a mapping of many records is side metadata)
        single = models and self.layout != "objaverse" and (len(models) == 1 or record is not None or meta_error)
        if single:
            yield self.folder_object(folder, _preferred(models), models, record, meta_error, meta_path)
            return
        for path in models:
            yield self.file_object(path)

    def folder_object(self, folder: Path, model: Path, models: list[Path], record: dict[str, Any] | None,
                      meta_error: str | None, meta_path: Path) -> Candidate:
        cand = self.file_object(model)
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
            if ident["name"]:
                cand.name = safe_text(ident["name"])
            if ident["category"]:
                cand.category = category_text(ident["category"])
            elif ident["name"]:
                cand.category = category_from_name(ident["name"], cand.category)
            cand.units, cand.up_axis = ident["units"], ident["up_axis"]
            if ident["license"]:
                cand.license = ident["license"]
        self._apply_licence(cand, folder)
        return cand

    def file_object(self, path: Path) -> Candidate:
        stem = safe_text(path.stem)
        found = self.side.lookup(path.stem, path.parent, self.root) if self.layout in ("auto", "objaverse") else None
        if found is not None or self.layout == "objaverse":
            cand = Candidate(SOURCE_OBJAVERSE, stem, stem, category_from_stem(stem, path.parent.name), path,
                             layout=SOURCE_OBJAVERSE)
            if found is not None:
                rec, side_file = found
                ident = record_identity(rec)
                cand.metadata = {"record": rec, "metadata_file": str(side_file)}
                if ident["name"]:
                    cand.name = safe_text(ident["name"])
                if ident["category"]:
                    cand.category = category_text(ident["category"])
                elif ident["name"]:
                    cand.category = category_from_name(ident["name"], cand.category)
                cand.license = ident["license"]
                cand.units, cand.up_axis = ident["units"], ident["up_axis"]
            else:
                cand.metadata = {"record": None}
        else:
            cand = Candidate(SOURCE_FOLDER, safe_text(str(path)), stem,
                             category_from_stem(stem, safe_text(path.parent.name)), path)
        reason = odd_name_reason(path.name)
        if reason:
            cand.error = reason
        elif path.suffix.lower() not in MESH_EXTENSIONS:
            cand.error = f"unsupported file type {path.suffix or '(none)'}"
        if not cand.error:
            self._apply_licence(cand, path.parent)
        return cand

    # helpers ---------------------------------------------------------------------------------
    @staticmethod
    def _json_object(path: Path, cand: Candidate) -> dict[str, Any] | None:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            cand.error = f"{path.name} does not parse: {exc}"
            return None
        if not isinstance(data, dict):
            cand.error = f"{path.name} is not a JSON object"
            return None
        return data

    @staticmethod
    def _read_licence_into(cand: Candidate, path: Path) -> None:
        cand.sidecars[path.name] = path
        try:
            cand.license = _read_licence(path)
        except OSError as exc:
            cand.error = f"unreadable licence file {path.name}: {exc.strerror}"

    # the walk --------------------------------------------------------------------------------
    def object_at(self, folder: Path) -> Candidate | None:
        """The object a folder is by itself (a path given directly), or None to walk it."""
        try:
            entries = _scan(folder)
        except OSError as exc:
            return broken_path_candidate(folder, exc)
        kind = self.object_kind(folder, entries)
        return self._make(kind, folder, entries) if kind else None

    def _make(self, kind: str, folder: Path, entries: list[os.DirEntry]) -> Candidate:
        if kind == SOURCE_GSO:
            return self.gso(folder, entries)
        if kind == SOURCE_OMNI:
            return self.omni(folder, entries)
        return self.dtc(folder, entries)

    def walk(self, folder: Path) -> Iterator[Candidate]:
        try:
            entries = [e for e in _scan(folder) if not e.name.startswith(".")]
        except OSError as exc:
            yield broken_path_candidate(folder, exc)
            return
        kind = self.object_kind(folder, entries)
        if kind:
            yield self._make(kind, folder, entries)
            return
        models: list[Path] = []
        subdirs: list[Path] = []
        for entry in entries:
            path = Path(entry.path)
            try:
                is_dir, is_file = entry.is_dir(), entry.is_file()
                if not is_dir and not is_file and entry.is_symlink():
                    os.stat(path)  # raises for a dangling or looping link
            except OSError as exc:
                if DTC_NAME.match(entry.name) or path.suffix.lower() in MESH_EXTENSIONS:
                    yield broken_path_candidate(path, exc)
                continue
            if is_dir:
                subdirs.append(path)
            elif is_file and path.suffix.lower() in MESH_EXTENSIONS:
                models.append(path)
        if models:
            yield from self.files(folder, entries, models)
        for sub in subdirs:
            yield from self.walk(sub)


def _licence_file(entries: list[os.DirEntry]) -> Path | None:
    for e in entries:
        if LICENCE_NAMES.match(e.name):
            try:
                if e.is_file():
                    return Path(e.path)
            except OSError:
                continue
    return None


def broken_path_candidate(path: Path, exc: OSError) -> Candidate:
    looks_dtc = bool(DTC_NAME.match(path.name))
    source = SOURCE_DTC if looks_dtc else SOURCE_FOLDER
    source_id = safe_text(path.name if looks_dtc else str(path))
    category = singular(DTC_NAME.match(path.name).group("category")) if looks_dtc else "unknown"  # type: ignore[union-attr]
    kind = "folder" if looks_dtc or not path.suffix else "path"
    return Candidate(source, source_id, safe_text(path.name), category,
                     error=f"unreadable {kind}: {exc.strerror or exc}", layout=source)


def discover(paths: Iterable[Path | str], *, layout: str = "auto",
             metadata_files: Iterable[Path | str] = ()) -> list[Candidate]:
    """Every object under ``paths`` (sorted walk, duplicates removed); a missing path, an unknown
    layout or an unusable ``--metadata`` file is a CatalogError."""
    if layout not in LAYOUTS:
        raise CatalogError(f"unknown layout {layout!r} (expected one of {', '.join(LAYOUTS)})")
    side = SideMetadata(Path(p) for p in metadata_files)
    found: dict[tuple[str, str], Candidate] = {}
    for raw in paths:
        path = Path(raw).expanduser()
        if not os.path.lexists(path):
            raise CatalogError(f"path not found: {raw}")
        path = path.resolve()
        if path.is_dir():
            walker = _Walker(path, layout, side)
            own = walker.object_at(path)
            items: Iterable[Candidate] = [own] if own is not None else walker.walk(path)
        elif path.is_file():
            walker = _Walker(path.parent, layout, side)
            items = [walker.file_object(path)]
        else:
            try:
                os.stat(path)
                items = [Candidate(SOURCE_FOLDER, safe_text(str(path)), safe_text(path.name), "unknown",
                                   error="not a regular file or folder")]
            except OSError as exc:
                items = [broken_path_candidate(path, exc)]
        for cand in items:
            found.setdefault((cand.source, cand.source_id), cand)
    return list(found.values())


def stage(cand: Candidate, staging_root: Path) -> None:
    """Link ``cand.staged`` side by side under ``staging_root`` and point ``model_path`` at the link.

    Symbolic links (a copy where links are not allowed); a stale link is replaced. The folder name is
    a hash of (source, source_id), so reruns reuse it."""
    if not cand.staged or cand.model_path is None or cand.error:
        return
    key = hashlib.sha256(f"{cand.source}\0{cand.source_id}".encode()).hexdigest()[:20]
    folder = staging_root / cand.source / key
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for name, real in cand.staged.items():
            link = folder / name
            link.parent.mkdir(parents=True, exist_ok=True)
            if link.is_symlink() or link.exists():
                if link.is_symlink() and Path(os.readlink(link)) == real.resolve():
                    continue
                link.unlink()
            try:
                link.symlink_to(real.resolve())
            except OSError:
                shutil.copyfile(real, link)
    except OSError as exc:
        cand.error = f"cannot stage the model's files under {folder}: {exc.strerror or exc}"
        return
    cand.metadata["source_model_path"] = str(cand.model_path)
    cand.model_path = folder / cand.model_path.name
