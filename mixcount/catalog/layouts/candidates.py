"""What every layout reader shares: the :class:`Candidate` it returns, the walker it reads through
(:class:`Walker`: the root, the forced layout, side metadata, inherited licences) and small readers of
folders, metadata records and licence files."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import mixcount.json_input as json_input
from mixcount.catalog.mesh import MESH_EXTENSIONS
from mixcount.catalog.naming import DTC_NAME, category_from_name, category_text, safe_text, singular
from mixcount.frame import UP_AXES, unit_scale
from mixcount.library_root import LibraryRoots, refusal, refuse
from mixcount.library_root import current as current_roots

SOURCE_DTC = "dtc"
SOURCE_GSO = "gso"
SOURCE_OBJAVERSE = "objaverse"
SOURCE_OMNI = "omniobject3d"
SOURCE_FOLDER = "folder"
# LICENSE, LICENCE.txt, COPYING, LICENSE-CC-BY-NC-4.0.txt (Amazon Berkeley Objects), license.md ...
LICENCE_NAMES = re.compile(r"^(licen[cs]e|copying)([-_.][\w.-]*)?$", re.IGNORECASE)
MODEL_PREFERENCE = (".glb", ".gltf", ".usdz", ".usd", ".usdc", ".usda", ".step", ".stp", ".obj", ".ply", ".stl")
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
    # files written there instead (a rewritten .mtl, an OBJ or glTF whose references left the library)
    staged_texts: dict[str, str | bytes] = field(default_factory=dict)
    # companion meshes of the model (collision meshes, LODs: not objects), by kind and file name
    companions: dict[str, Path] = field(default_factory=dict)
    collision_source: Path | None = None  # a collision companion: the physics proxy is built from it
    up_reason: str | None = None  # why the object has its up axis (recorded with it)
    warnings: list[str] = field(default_factory=list)  # what ingest tolerated (reported, not broken)
    units_reason: str | None = None  # why ``units`` (a metadata entry, a description's scale): recorded with it
    # the model files that are parts of this one object (merged in their common frame, with each part's
    # 4x4 placement from a description), and the rule that made them one (:mod:`.parts`)
    parts: list[tuple[Path, Any]] = field(default_factory=list)
    parts_rule: str | None = None
    # the colour a description (URDF/SDF/MJCF) gives each visual mesh, by file name (RGBA 0..1): applied
    # to a mesh that carries no colour of its own (:mod:`mixcount.catalog.derived`)
    colours: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)
    # the folders its files may come from (the library named, the extra roots allowed): set by the walk
    roots: LibraryRoots | None = None
    # metadata entries of another meaning, ignored: (entry, why), said once per library in the summary
    ignored: list[tuple[str, str]] = field(default_factory=list)


class Walker(Protocol):
    """What a layout reader may ask of the walk (:class:`mixcount.catalog.layouts.discovery.TreeWalker`)."""

    root: Path  # the path given; licences are inherited up to it
    layout: str  # the forced layout, or "auto"
    side: Any  # the side metadata files (mixcount.catalog.layouts.objaverse.SideMetadata)

    def apply_licence(self, cand: Candidate, folder: Path) -> None: ...

    def file_object(self, path: Path) -> Candidate: ...


def model_files_in(entries: list[os.DirEntry]) -> list[Path]:
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


def preferred_model(files: list[Path]) -> Path:
    """The main model among several files of one object: GLB first, STL last, then by name."""
    return min(files, key=lambda p: (MODEL_PREFERENCE.index(p.suffix.lower()), p.name))


def scan_folder(folder: Path) -> list[os.DirEntry]:
    """A folder's entries by name, less the symbolic links that lead outside the library of the walk under
    way (:func:`mixcount.library_root.bounded`): those are not followed, and noted once as refused."""
    entries = sorted(os.scandir(folder), key=lambda e: e.name)
    roots = current_roots()
    if roots is None:
        return entries
    kept = []
    for entry in entries:
        try:
            link = entry.is_symlink()
        except OSError:
            link = False
        if link and not roots.contains(entry.path):
            target = os.path.realpath(entry.path)
            refuse(Path(entry.path), f"a link to {target}, outside the library: not followed "
                                     "(allow its folder with --allow-root to use it)")
            continue
        kept.append(entry)
    return kept


def is_dir(entry: os.DirEntry) -> bool:
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
    """name, category, licence, units, up axis from a metadata record (any of the usual field names).
    A ``units`` or ``up_axis`` of another meaning (``"unknown"``, a list) is left out: :func:`ignored_entries`
    says which."""
    lic = _first(record, LICENCE_FIELDS)
    if lic is not None:
        lic = LICENCE_SLUGS.get(lic.strip().lower(), lic)
    category = _first(record, CATEGORY_FIELDS)
    if category is not None and category.strip().lower() in ("none", "null", "unknown", "other", ""):
        category = None
    units = record_units(record.get("units"))
    return {"name": _first(record, NAME_FIELDS), "category": category, "license": lic, "units": units,
            "up_axis": record_up_axis(record.get("up_axis"))}


def record_units(value: Any) -> str | None:
    """A metadata ``units`` entry as text: a unit name (``"mm"``) or metres per unit, written as a string
    (``"0.05"``) or as a JSON number (``0.05``); None for anything else (``"unknown"``, a list, 0)."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        text = f"{value:g}" if value > 0 else None
    else:
        text = value.strip() if isinstance(value, str) and value.strip() else None
    if text is None:
        return None
    try:
        unit_scale(text)
    except ValueError:
        return None
    return text


def record_up_axis(value: Any) -> str | None:
    """A metadata ``up_axis`` entry: X, Y or Z (any case, ``+Z`` too); None for anything else."""
    if not isinstance(value, str):
        return None
    up = value.strip().upper().lstrip("+")
    return up if up in UP_AXES else None


# the entries the project reads from a metadata record, with what each must be (docs/ingest.md)
READ_ENTRIES = {"units": "a unit (mm, cm, m, in, ft) or metres per unit", "up_axis": "X, Y or Z",
                "parts": "merge, separate or auto"}


def ignored_entries(record: dict[str, Any], file: str = "metadata.json") -> list[tuple[str, str]]:
    """The entries of ``record`` the project reads whose value cannot mean what it reads them for
    (``"parts": 3``, a count of parts; ``"units": "unknown"``; a list where a name is expected), each as
    (``file: entry value``, what it must be): ignored, said once per library, never fatal."""
    out = []
    checks = {"units": record_units, "up_axis": record_up_axis,
              "parts": lambda v: v.strip().lower() if isinstance(v, str) and v.strip().lower() in
              ("auto", "merge", "separate") else None}
    for key, check in checks.items():
        if key in record and record[key] is not None and check(record[key]) is None:
            out.append((f"{file}: {key} {_shown(record[key])}", READ_ENTRIES[key]))
    for keys, what in ((NAME_FIELDS, "name"), (CATEGORY_FIELDS, "category"), (LICENCE_FIELDS, "licence")):
        for key in keys:
            if key in record and record[key] is not None and _text(record[key]) is None:
                out.append((f"{file}: {key} {_shown(record[key])}", f"a {what} as text"))
    return out


def _shown(value: Any) -> str:
    """A metadata value as said in the summary: short, one line."""
    import json

    try:
        text = json.dumps(value, default=str)
    except (TypeError, ValueError):
        text = repr(value)
    return safe_text(text if len(text) <= 40 else text[:37] + "...")


def apply_identity(cand: Candidate, ident: dict[str, str | None]) -> None:
    """A metadata record's identity (:func:`record_identity`) onto ``cand``: its name and category when it
    names them (a name alone refines the category), its units and up axis. Licences are the caller's:
    layouts differ in whether a record without one clears the candidate's."""
    if ident["name"]:
        cand.name = safe_text(ident["name"])
    if ident["category"]:
        cand.category = category_text(ident["category"])
    elif ident["name"]:
        cand.category = category_from_name(ident["name"], cand.category)
    cand.units, cand.up_axis = ident["units"], ident["up_axis"]
    cand.units_reason = "stated in the object's metadata" if ident["units"] else None


def read_licence(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace")[:LICENCE_CHARS].strip()


def json_object(path: Path, cand: Candidate) -> dict[str, Any] | None:
    """A side file's JSON object, or None with a warning on ``cand`` saying why it was not read (it does
    not parse, it is not an object, it leads outside the library): the object is ingested without it."""
    reason = refusal(path, path.name)
    if reason:
        cand.warnings.append(f"{path.name} not read: {reason}")
        return None
    try:
        data = json_input.read(path)  # too deep / too large: a ValueError of one line
    except (OSError, ValueError) as exc:
        cand.warnings.append(f"{path.name} does not parse, not used: {exc}")
        return None
    if not isinstance(data, dict):
        cand.warnings.append(f"{path.name} is not a JSON object, not used")
        return None
    cand.ignored.extend(ignored_entries(data, path.name))
    return data


def read_licence_into(cand: Candidate, path: Path) -> None:
    cand.sidecars[path.name] = path
    try:
        cand.license = read_licence(path)
    except OSError as exc:
        cand.error = f"unreadable licence file {path.name}: {exc.strerror}"


def licence_file_in(entries: list[os.DirEntry]) -> Path | None:
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
