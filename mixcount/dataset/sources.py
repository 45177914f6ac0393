"""Where each file a packaged dataset holds came from, and the rule that only library files get in (issue 68).

``compose --package-assets`` and ``mixcount package`` turn the links of ``OUT/assets/`` into copies, and a
dataset gets published. Before this check a model whose texture reference left its library (a glTF image
URI ``../../../secret/secret.png``, an MTL ``map_Kd /abs/path.png``) was read by the USD conversion into
the catalog's ``<hash>_tex/`` and copied from there into the dataset without a word. :class:`CatalogSources`
gives each entry of ``OUT/assets/`` a :class:`Verdict` from the catalog that made the dataset:

* ``<hash>.usdc``, ``<hash>_tex/``, ``<hash>_collision.usdc``, ``sources/<hash>/<file>``: the converted
  asset of the catalog objects whose content hash is ``<hash>``. It is packaged when the object's model
  file and every file the model names (an OBJ's ``mtllib`` and its maps, a glTF's buffers and images, a
  COLLADA ``init_from``, a USD model's layers and assets: :func:`model_references`) resolve inside the
  object's library (:class:`mixcount.library_root.LibraryRoots`: the folder ``catalog ingest`` was given,
  the catalog's own data folder, where ingest writes the files it derives, and ``[ingest] extra_roots``
  as configured NOW: a root allowed at ingest and no longer allowed refuses its files);
* ``environments/<file>``: one of bpy's bundled HDRIs, or an environment map ingested into the catalog;
* ``materials/<digest>/<file>``: a map of a floor material ingested into the catalog.

Anything else, or an entry whose model reaches outside, is refused: never copied, its link taken out of
the dataset, one line naming it. Each source is written as the library's name, an id (the name and a
hash of its real location: no absolute path of this machine) and the path relative to the library
(:class:`FileSource`); ``OUT/package.json`` lists every packaged file with them (:mod:`mixcount.dataset.package`).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Iterable, Optional

from mixcount.library_root import LibraryRoots, OutsideLibraryError

CATALOG_LIBRARY = "catalog"  # files ingest derived (staged copies, converted STEP models) in the catalog's data folder
BPY_LIBRARY = "bpy"  # bpy's bundled HDRIs

_MTL_MAPS = re.compile(r"^\s*(map_\w+|bump|disp|decal|refl|norm)\s+(.+?)\s*$", re.IGNORECASE)
_DAE_IMAGE = re.compile(r"<init_from>\s*([^<]+?)\s*</init_from>")


@dataclass(frozen=True)
class FileSource:
    """A library file as a dataset records it: no absolute path of this machine."""

    library: str  # the library folder's name ("demo"), "catalog" or "bpy"
    library_id: str  # "<name>#<sha256 of its real location, 12 hex>"
    path: str  # posix, relative to the library folder

    def to_dict(self) -> dict[str, str]:
        return {"library": self.library, "library_id": self.library_id, "path": self.path}


@dataclass
class Verdict:
    """Whether one entry of ``OUT/assets/`` may be packaged: its sources, or why it is refused."""

    entry: str
    sources: list[FileSource] = field(default_factory=list)
    object_ids: list[int] = field(default_factory=list)
    refused: Optional[str] = None  # the one line said (may name a path of this machine: never recorded)
    why: str = ""  # the reason as package.json records it (no path)

    @property
    def ok(self) -> bool:
        return self.refused is None


def library_source(path: str | os.PathLike[str], root: str | os.PathLike[str], name: Optional[str] = None) -> FileSource:
    """``path`` (inside ``root``) as a :class:`FileSource` of the library at ``root``."""
    real_root = os.path.realpath(os.fspath(root))
    real = os.path.realpath(os.fspath(path))
    label = name or Path(real_root).name or "/"
    digest = hashlib.sha256(real_root.encode("utf-8", "surrogateescape")).hexdigest()[:12]
    return FileSource(label, f"{label}#{digest}", Path(os.path.relpath(real, real_root)).as_posix())


# ------------------------------------------------------------------------------------ a model's references


def _obj_references(model: Path) -> list[tuple[str, Path]]:
    refs: list[tuple[str, Path]] = []
    text = model.read_text(encoding="utf-8", errors="replace")
    for line in text.splitlines():
        if line.startswith("mtllib"):
            name = line[len("mtllib"):].strip()
            if name:
                refs.append((name, model.parent))
    for name, base in list(refs):
        try:
            mtl = LibraryRoots(("/",)).resolve(name, base, "material library")
            lines = mtl.read_text(encoding="utf-8", errors="replace").splitlines()
        except (OutsideLibraryError, OSError):
            continue  # checked as a reference itself; nothing more to read from it here
        for ln in lines:
            m = _MTL_MAPS.match(ln)
            if m:
                refs.append((m.group(2).split()[-1], mtl.parent))
    return refs


def _gltf_json(model: Path) -> dict[str, Any]:
    data = model.read_bytes()
    if model.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            return {}
        length, kind = struct.unpack_from("<II", data, 12)
        if kind != 0x4E4F534A:  # "JSON"
            return {}
        return dict(json.loads(data[20:20 + length].decode("utf-8")))
    return dict(json.loads(data.decode("utf-8")))


def _gltf_references(model: Path) -> list[tuple[str, Path]]:
    try:
        doc = _gltf_json(model)
    except (ValueError, UnicodeDecodeError, struct.error):
        return []
    uris = [b.get("uri") for b in doc.get("buffers", []) or []] + [i.get("uri") for i in doc.get("images", []) or []]
    return [(u, model.parent) for u in uris if isinstance(u, str) and u and not u.startswith("data:")]


def _usd_references(model: Path) -> list[tuple[str, Path]]:
    from pxr import Sdf, UsdUtils

    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(model)))
    found = [str(layer.realPath or layer.identifier) for layer in layers] + [str(a) for a in assets]
    return [(p, model.parent) for p in found + [str(u) for u in unresolved] if p]


def model_references(model: Path) -> list[tuple[str, Path]]:
    """``(reference, folder it is relative to)`` of every file ``model`` names (module docstring); a format
    that names none (PLY, STL, OFF, ...) gives an empty list."""
    suffix = model.suffix.lower()
    try:
        if suffix == ".obj":
            return _obj_references(model)
        if suffix in (".gltf", ".glb"):
            return _gltf_references(model)
        if suffix in (".usd", ".usda", ".usdc", ".usdz"):
            return _usd_references(model)
        if suffix == ".dae":
            text = model.read_text(encoding="utf-8", errors="replace")
            return [(m, model.parent) for m in _DAE_IMAGE.findall(text)]
    except OSError:
        return []
    return []


# ------------------------------------------------------------------------------------ the catalog's verdicts


def _tail(path: str) -> tuple[str, ...]:
    """The parts of a path as ingest was given it, leading ``.`` / ``..`` dropped (a relative path's
    folder is unknown: it matches any folder that ends so)."""
    parts = [p for p in PurePosixPath(path.replace("\\", "/")).parts if p not in (".", "..", "/")]
    return tuple(parts)


@dataclass
class _Object:
    object_id: int
    model_path: str
    ingest_paths: list[str]


class CatalogSources:
    """Verdicts for the entries of a dataset composed from ``catalog`` (module docstring);
    ``extra_roots``: the folders allowed beyond each library NOW (``[ingest] extra_roots``)."""

    def __init__(self, catalog: Any, extra_roots: Iterable[str | os.PathLike[str]]) -> None:
        from sqlalchemy import select

        from mixcount.catalog.models import CatalogObject, Environment, IngestRun, Material

        self.data_dir = Path(os.path.realpath(catalog.data_dir))
        self.extra = [str(e) for e in extra_roots]
        self.by_hash: dict[str, list[_Object]] = {}
        self.environments: dict[str, str] = {}  # real path -> recorded path
        self.materials: set[str] = set()
        self._cache: dict[str, Verdict] = {}
        with catalog.session() as session:
            runs = {r.id: _run_paths(r.paths) for r in session.execute(select(IngestRun)).scalars()}
            every_run = [p for paths in runs.values() for p in paths]
            for o in session.execute(select(CatalogObject)).scalars():
                own = runs.get(o.ingest_run_id or -1, [])
                obj = _Object(int(o.id), str(o.model_path), own + [p for p in every_run if p not in own])
                for key in {o.content_hash or "", hashlib.sha256(str(o.model_path).encode()).hexdigest()}:
                    if key:
                        self.by_hash.setdefault(key, []).append(obj)
            for e in session.execute(select(Environment)).scalars():
                self.environments[os.path.realpath(e.path)] = e.path
            for m in session.execute(select(Material)).scalars():
                for p in json.loads(m.maps_json or "{}").values():
                    self.materials.add(os.path.realpath(str(p)))

    # -------------------------------------------------------------------------------- objects

    def _library_of(self, obj: _Object) -> Optional[Path]:
        """The folder ``catalog ingest`` was given that holds the object's model (the outermost one when
        several do); a relative one matches the model's ancestor folder that ends in its parts."""
        model = Path(os.path.realpath(obj.model_path))
        best: Optional[Path] = None
        for given in obj.ingest_paths:
            cands: list[Path] = []
            if os.path.isabs(given):
                cands.append(Path(os.path.realpath(given)))
            else:
                tail = _tail(given)
                cands += [a for a in model.parents if tail and a.parts[-len(tail):] == tail]
            for c in cands:
                root = c.parent if c.is_file() else c
                if root == model or root in model.parents:
                    if best is None or root in best.parents:
                        best = root
        return best

    def object_verdict(self, obj: _Object) -> Verdict:
        """The object's model and every file it names inside its library's roots, or why not."""
        cached = self._cache.get(f"object:{obj.object_id}")
        if cached is not None:
            return cached
        verdict = Verdict(entry=f"object {obj.object_id}", object_ids=[obj.object_id])
        self._cache[f"object:{obj.object_id}"] = verdict
        model = Path(obj.model_path)
        library = self._library_of(obj)
        in_data = self.data_dir == Path(os.path.realpath(model)) or self.data_dir in Path(os.path.realpath(model)).parents
        base_root = library if library is not None else (self.data_dir if in_data else None)
        if base_root is None:
            verdict.refused = (f"object {obj.object_id}'s model {model.name} lies in no library folder this catalog "
                               "ingested")
            verdict.why = "model in no library of this catalog"
            return verdict
        roots = LibraryRoots.of(base_root, [str(self.data_dir), *self.extra])
        named = {roots.roots[0]: (Path(roots.roots[0]).name if library is not None else CATALOG_LIBRARY),
                 str(self.data_dir): CATALOG_LIBRARY}

        def source(real: Path) -> FileSource:
            holder = next(r for r in roots.roots if str(real) == r or str(real).startswith(r.rstrip(os.sep) + os.sep))
            return library_source(real, holder, named.get(holder))

        try:
            verdict.sources.append(source(roots.check(model, "model file")))
        except OutsideLibraryError:
            verdict.refused = f"object {obj.object_id}'s model {model.name} lies outside its library"
            verdict.why = "model outside its library"
            return verdict
        try:
            for ref, base in model_references(model):
                verdict.sources.append(source(roots.resolve(ref, base, "reference")))
        except OutsideLibraryError as exc:
            verdict.sources = []
            verdict.refused = (f"object {obj.object_id}'s model {model.name} names {exc.reference}, which "
                               f"{exc.reason.split(' (')[0].replace('reference ', '')}")
            verdict.why = "its model names a file outside its library"
        return verdict

    # -------------------------------------------------------------------------------- entries

    def verdict(self, rel: str, target: Optional[Path]) -> Verdict:
        """The verdict of ``OUT/assets/<rel>``; ``target``: the file it would be copied from (its link's
        target, or what a search found) or, for an entry that is already a copy, that copy."""
        parts = rel.split("/")
        if parts[0] == "environments" and len(parts) == 2:
            return self._environment(rel, target)
        if parts[0] == "materials" and len(parts) == 3:
            return self._material(rel, target)
        if parts[0] == "sources" and len(parts) == 3:
            return self._asset(rel, parts[1])
        if len(parts) == 1:
            name = parts[0]
            for suffix in ("_collision.usdc", ".usdc", "_tex"):
                if name.endswith(suffix):
                    return self._asset(rel, name[: -len(suffix)])
        return Verdict(rel, refused=f"{rel}: not a file of this catalog's libraries", why="not a library file")

    def _asset(self, rel: str, key: str) -> Verdict:
        objects = self.by_hash.get(key, [])
        if not objects:
            return Verdict(rel, refused=f"{rel}: the asset of no object of this catalog (content hash {key[:12]})",
                           why="no object of this catalog")
        out = Verdict(rel, object_ids=sorted({o.object_id for o in objects}))
        for obj in objects:
            v = self.object_verdict(obj)
            if not v.ok:
                return Verdict(rel, object_ids=out.object_ids, refused=f"{rel}: {v.refused}", why=v.why)
            out.sources += [s for s in v.sources if s not in out.sources]
        return out

    def _environment(self, rel: str, target: Optional[Path]) -> Verdict:
        from mixcount.usd.portable import bpy_dir

        real = Path(os.path.realpath(target)) if target is not None else None
        bpy = bpy_dir()
        if real is not None and bpy is not None and bpy in real.parents:
            return Verdict(rel, sources=[library_source(real, bpy, BPY_LIBRARY)])
        if real is not None and str(real) in self.environments:
            return Verdict(rel, sources=[library_source(real, real.parent)])
        # a copy (bpy's HDRIs are copied in while composing, an earlier package copied the rest) or a file
        # found by search: the same name and size as one of bpy's or an ingested map
        name, size = Path(rel).name, _size(real)
        if bpy is not None:
            try:
                from mixcount.scene.bundled_environments import bundled_hdri_dir

                bundled = bundled_hdri_dir() / name
                if bundled.is_file() and _size(bundled) == size:
                    return Verdict(rel, sources=[library_source(bundled, bpy, BPY_LIBRARY)])
            except Exception:  # noqa: BLE001 - a bpy without its HDRIs: not one of them
                pass
        for path in self.environments:
            if Path(path).name == name and _size(Path(path)) == size:
                return Verdict(rel, sources=[library_source(path, Path(path).parent)])
        return Verdict(rel, refused=f"{rel}: not one of bpy's HDRIs nor an environment map ingested into this catalog",
                       why="not an environment map of this catalog")

    def _material(self, rel: str, target: Optional[Path]) -> Verdict:
        real = Path(os.path.realpath(target)) if target is not None else None
        if real is not None and str(real) in self.materials:
            return Verdict(rel, sources=[library_source(real, real.parent.parent)])
        name, size = Path(rel).name, _size(real)
        for path in sorted(self.materials):
            if Path(path).name == name and _size(Path(path)) == size:
                return Verdict(rel, sources=[library_source(path, Path(path).parent.parent)])
        return Verdict(rel, refused=f"{rel}: not a map of a floor material ingested into this catalog",
                       why="not a floor material of this catalog")


def _size(path: Optional[Path]) -> Optional[int]:
    try:
        return path.stat().st_size if path is not None else None
    except OSError:
        return None


def _run_paths(text: Optional[str]) -> list[str]:
    try:
        paths = json.loads(text or "[]")
    except ValueError:
        return []
    return [str(p) for p in paths if isinstance(p, str) and p]
