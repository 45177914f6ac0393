"""The walk: every folder under a path is offered to the folder layouts in their order (the first whose
``detect`` claims it reads it); the model files of a folder none claims go to the file-level readers
(Objaverse's side metadata, then the plain folder reading). Licences are inherited from the nearest
licence file up to the path given.

Folder layouts are the modules of this package that define ``detect`` and ``read`` (with ``NAME`` and
``PRIORITY``), found when the package is imported: a new folder layout is one new module."""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
import shutil
import unicodedata
from pathlib import Path
from types import ModuleType
from typing import Iterable, Iterator

from mixcount.atomic import write_bytes_atomic
from mixcount.catalog.layouts import folder as folder_layout
from mixcount.catalog.layouts import objaverse
from mixcount.catalog.layouts.candidates import (
    LICENCE_NAMES,
    SOURCE_FOLDER,
    SOURCE_GSO,
    Candidate,
    broken_path_candidate,
    read_licence,
    scan_folder,
)
from mixcount.catalog.mesh import MESH_EXTENSIONS
from mixcount.catalog.model_files import relink_textures, seal_gltf
from mixcount.catalog.naming import DTC_NAME, odd_name_reason, safe_text
from mixcount.errors import CatalogError
from mixcount.library_root import LibraryRoots, bounded


def _folder_layouts() -> tuple[ModuleType, ...]:
    """The layout modules that recognise an object folder by itself, in ``PRIORITY`` order."""
    package = __name__.rpartition(".")[0]  # by name and folder: the package imports this module (no circle)
    found = []
    for info in pkgutil.iter_modules([str(Path(__file__).parent)]):
        module = importlib.import_module(f"{package}.{info.name}")
        if hasattr(module, "detect") and hasattr(module, "read"):
            found.append(module)
    return tuple(sorted(found, key=lambda m: m.PRIORITY))


# Model formats ingest does not read, found in real libraries: a walk lists them (``TreeWalker.skipped``,
# ``discover(skipped=...)``) instead of passing over them without a word. Convert them to GLB first.
UNREAD_MODEL_FORMATS = {
    ".fbx": "Autodesk FBX", ".dae": "COLLADA", ".blend": "Blender file", ".3ds": "3ds Max 3DS", ".max": "3ds Max",
    ".c4d": "Cinema 4D", ".ma": "Maya ASCII", ".mb": "Maya binary", ".abc": "Alembic", ".x3d": "X3D",
    ".wrl": "VRML", ".3mf": "3MF", ".off": "OFF", ".lwo": "LightWave", ".skp": "SketchUp", ".step": "STEP CAD",
    ".stp": "STEP CAD", ".iges": "IGES CAD", ".igs": "IGES CAD",
}

FOLDER_LAYOUTS = _folder_layouts()
# every layout name ``discover`` accepts ("auto" reads each folder by itself)
LAYOUTS = ("auto", *sorted(m.NAME for m in FOLDER_LAYOUTS + (objaverse,)), folder_layout.NAME)


class TreeWalker:
    """Walks one root path and yields candidates (see the module docstring for the rules)."""

    def __init__(self, root: Path, layout: str, side: objaverse.SideMetadata, parts: str = "auto",
                 roots: LibraryRoots | None = None) -> None:
        self.root = root
        # the boundary: the folder named and the extra roots allowed (docs/ingest.md, "The library root is
        # the boundary"); links and files that leave it are not followed, and listed in ``refused``
        self.roots = roots or LibraryRoots.of(root)
        self.refused: list[tuple[Path, str]] = []
        self.parts = parts  # catalog ingest --parts: merge | separate | auto (:mod:`.parts`)
        self.layout = layout
        self.side = side
        self._licences: dict[Path, tuple[str, Path] | None] = {}
        self.skipped: list[tuple[Path, str]] = []  # (model file in a format not read, why)
        self.repeats: list[tuple[Path, str]] = []  # (a folder not walked again: a loop, a repeated target; why)
        self._walked: dict[tuple[int, int], Path] = {}  # real folder (device, inode) -> where it was walked

    def _folder_licence(self, folder: Path) -> tuple[str, Path] | None:
        if folder not in self._licences:
            found = None
            try:
                for e in scan_folder(folder):
                    # inside the roots, or (an object folder named itself) a real file of the folder above
                    if LICENCE_NAMES.match(e.name) and e.is_file() and (
                            self.roots.contains(e.path) or os.path.realpath(e.path) == os.path.abspath(e.path)):
                        found = (read_licence(Path(e.path)), Path(e.path))
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

    def apply_licence(self, cand: Candidate, folder: Path) -> None:
        if cand.license is None:
            lic = self.inherited_licence(folder)
            if lic is not None:
                cand.license = lic[0]
                cand.sidecars.setdefault(f"licence:{lic[1].name}", lic[1])

    def folder_object(self, folder: Path, entries: list[os.DirEntry]) -> Candidate | None:
        """The object a folder layout reads ``folder`` as, or None when no folder layout claims it."""
        for layout in FOLDER_LAYOUTS:
            if layout.detect(self, folder, entries):
                cand: Candidate = layout.read(self, folder, entries)
                return cand
        return None

    def file_object(self, path: Path) -> Candidate:
        """One model file as an object: Objaverse's reading when its side metadata knows it, else a plain one."""
        cand = objaverse.read_file(self, path) or folder_layout.read_file(self, path)
        reason = odd_name_reason(path.name)
        if reason:
            cand.error = reason
        elif path.suffix.lower() not in MESH_EXTENSIONS:
            cand.error = f"unsupported file type {path.suffix or '(none)'}"
        if not cand.error:
            self.apply_licence(cand, path.parent)
        return cand

    def object_at(self, folder: Path) -> Candidate | None:
        """The object a folder is by itself (a path given directly), or None to walk it."""
        try:
            entries = scan_folder(folder)
        except OSError as exc:
            return broken_path_candidate(folder, exc)
        return self.folder_object(folder, entries)

    def walk(self, folder: Path) -> Iterator[Candidate]:
        """Every object under ``folder``, each real folder read once. Folders reached through a symbolic
        link are walked after every real one (an object keeps its real path where it has one); a folder
        reached again (a link to a folder above it, i.e. a loop, or a second link to one folder) is not
        walked again but listed in ``repeats``. A stack, not recursion: depth is bounded by paths only."""
        pending: list[Path] = [folder]
        linked: list[Path] = []
        while pending or linked:
            here = pending.pop() if pending else linked.pop(0)
            subdirs: list[Path] = []
            yield from self._read_folder(here, subdirs, linked)
            pending.extend(reversed(subdirs))

    def _read_folder(self, folder: Path, subdirs: list[Path], linked: list[Path]) -> Iterator[Candidate]:
        """The objects of one folder; its sub-folders are appended to ``subdirs`` (``linked`` for links)."""
        try:
            st = os.stat(folder)
            entries = [e for e in scan_folder(folder) if not e.name.startswith(".")]
        except OSError as exc:
            yield broken_path_candidate(folder, exc)
            return
        first = self._walked.setdefault((st.st_dev, st.st_ino), folder)
        if first != folder:
            loop = " (a loop: a link to a folder above it)" if first in folder.parents else ""
            self.repeats.append((folder, f"leads to {first}, already walked{loop}"))
            return
        own = self.folder_object(folder, entries)
        if own is not None:
            yield own
            return
        models: list[Path] = []
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
                (linked if entry.is_symlink() else subdirs).append(path)
            elif is_file and path.suffix.lower() in MESH_EXTENSIONS:
                models.append(path)
            elif is_file and path.suffix.lower() in UNREAD_MODEL_FORMATS:
                self.skipped.append((path, f"{UNREAD_MODEL_FORMATS[path.suffix.lower()]} ({path.suffix.lower()}) "
                                           "is not a format ingest reads"))
        if models:
            yield from folder_layout.read_models(self, folder, entries, models)

    def refuse_outside(self, cand: Candidate) -> None:
        """Every file of ``cand`` inside the roots (after links are followed): a model file or part outside
        breaks it (the walk met it through a folder link the listing could not see: ``meshes/`` -> /x),
        a companion, side file or staged texture outside is dropped with a warning naming it and why."""
        cand.roots = self.roots
        if cand.error:
            return
        for path in [p for p in (cand.model_path, *(p for p, _m in cand.parts)) if p is not None]:
            if not self.roots.contains(path):
                cand.error = (f"model file {safe_text(str(path))} leads outside the library "
                              f"({safe_text(os.path.realpath(path))}): not read; allow its folder with --allow-root")
                self.refused.append((path, "a model file outside the library: not read"))
                return
        if cand.collision_source is not None and not self.roots.contains(cand.collision_source):
            cand.collision_source = None
        for table, what in ((cand.companions, "companion mesh"), (cand.sidecars, "side file"),
                            (cand.staged, "staged file")):
            for key, path in list(table.items()):
                if not self.roots.contains(path):
                    del table[key]
                    cand.warnings.append(f"{what} {safe_text(str(path))} leads outside the library "
                                         f"({safe_text(os.path.realpath(path))}): not read")
        if cand.staged and (cand.model_path is None or cand.model_path.name not in cand.staged
                            or any(w.startswith("staged file") for w in cand.warnings)):
            cand.staged, cand.staged_texts = {}, {}  # staged again by stage(): its materials sealed

    def refuse_unusable_names(self, cand: Candidate) -> None:
        """``cand`` broken when a folder or file name on the way to its files (from the path given down)
        cannot be a path here: control characters (a newline), line separators, bytes that are not UTF-8.
        The catalog, the workers and the exports could not name its files."""
        if cand.error:
            return
        files = [cand.model_path, cand.collision_source, *cand.staged.values(), *cand.companions.values()]
        for path in (f for f in files if f is not None):
            try:
                parts = path.relative_to(self.root.parent).parts
            except ValueError:
                parts = path.parts
            for name in parts:
                reason = unusable_name_reason(name)
                if reason:
                    cand.error = f"{reason}: {safe_text(str(path))} cannot be named here; rename it"
                    return


def unusable_name_reason(name: str) -> str | None:
    """Why a folder or file name cannot be carried as a path (None when it can). Blanks and other
    odd-but-valid characters pass: only what breaks one-line paths and text encodings is refused."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return f"name {ascii(name)} is not valid UTF-8"
    bad = sorted({c for c in name if unicodedata.category(c) in ("Cc", "Zl", "Zp")})
    if bad:
        return f"name {ascii(name)} has control characters {ascii(''.join(bad))}"
    return None


def _drop_linked_copies(found: list[Candidate], repeats: list[tuple[Path, str]]) -> list[Candidate]:
    """One object per real model file: a candidate reached through a symbolic link to a model file
    another candidate already holds (at its real path, else the first link) is listed in ``repeats``."""
    by_real: dict[str, list[Candidate]] = {}
    for cand in found:
        if cand.model_path is not None and not cand.error:
            by_real.setdefault(os.path.realpath(cand.model_path), []).append(cand)
    dropped: set[int] = set()
    for real, group in by_real.items():
        linked = [c for c in group if os.path.abspath(c.model_path or "") != real]
        if len(group) < 2 or not linked:
            continue
        keep = next((c for c in group if c not in linked), linked[0])
        for cand in linked:
            if cand is not keep:
                dropped.add(id(cand))
                repeats.append((cand.model_path or Path(real), f"the same file as {keep.model_path}, already read"))
    return [c for c in found if id(c) not in dropped]


def discover(paths: Iterable[Path | str], *, layout: str = "auto",
             metadata_files: Iterable[Path | str] = (),
             skipped: list[tuple[Path, str]] | None = None,
             repeats: list[tuple[Path, str]] | None = None, parts: str = "auto",
             allowed: Iterable[Path | str] = (),
             refused: list[tuple[Path, str]] | None = None) -> list[Candidate]:
    """Every object under ``paths`` (sorted walk, duplicates removed); a missing path, an unknown
    layout or an unusable ``--metadata`` file is a CatalogError. Model files a walk passes over (formats
    in :data:`UNREAD_MODEL_FORMATS`) are appended to ``skipped`` as (path, reason) when it is given;
    folders and linked model files not read again (each real folder and file is read once: loops and
    repeated link targets) to ``repeats``. Objects whose path has a name that cannot be a path here
    (control characters) are broken (:meth:`TreeWalker.refuse_unusable_names`).

    Each path is a library whose folder is its boundary, widened by ``allowed`` (``--allow-root``,
    ``[ingest] extra_roots``): a link that leads outside is not followed and a file outside is not read
    (:meth:`TreeWalker.refuse_outside`); each is appended once to ``refused`` as (path, why)."""
    if layout not in LAYOUTS:
        raise CatalogError(f"unknown layout {layout!r} (expected one of {', '.join(LAYOUTS)})")
    side = objaverse.SideMetadata(Path(p) for p in metadata_files)
    found: dict[tuple[str, str], Candidate] = {}
    again: list[tuple[Path, str]] = []
    for raw in paths:
        path = Path(raw).expanduser()
        if not os.path.lexists(path):
            raise CatalogError(f"path not found: {raw}")
        path = path.resolve()
        top = path if path.is_dir() else path.parent
        walker = TreeWalker(top, layout, side, parts, LibraryRoots.of(top, allowed))
        with bounded(walker.roots, walker.refused):
            if path.is_dir():
                own = walker.object_at(path)
                items: Iterable[Candidate] = [own] if own is not None else walker.walk(path)
            elif path.is_file():
                items = [walker.file_object(path)]
            else:
                try:
                    os.stat(path)
                    items = [Candidate(SOURCE_FOLDER, safe_text(str(path)), safe_text(path.name), "unknown",
                                       error="not a regular file or folder")]
                except OSError as exc:
                    items = [broken_path_candidate(path, exc)]
            for cand in items:
                walker.refuse_outside(cand)
                walker.refuse_unusable_names(cand)
                found.setdefault((cand.source, cand.source_id), cand)
        if skipped is not None:
            skipped.extend(walker.skipped)
        again.extend(walker.repeats)
        if refused is not None:
            refused.extend(r for r in walker.refused if r not in refused)
    kept = _drop_linked_copies(list(found.values()), again)
    if repeats is not None:
        repeats.extend(again)
    return kept


def _relink(cand: Candidate) -> None:
    """A model whose references must change to be read from a staged copy is staged with them rewritten:
    an OBJ whose textures are found only by name, or whose material or textures leave the library
    (:func:`mixcount.catalog.model_files.relink_textures`), a glTF whose images leave it
    (:func:`mixcount.catalog.model_files.seal_gltf`), so that analysis, renders and USD all see the same
    files, and none from outside the library."""
    assert cand.model_path is not None
    roots = cand.roots or LibraryRoots.of(cand.model_path.parent)
    if cand.model_path.suffix.lower() in (".gltf", ".glb"):
        relinked = seal_gltf(cand.model_path, roots)
    else:  # a GSO model's textures are in materials/textures/ (staged by name beside its MTL)
        also = (cand.model_path.parent.parent / "materials" / "textures",) if cand.layout == SOURCE_GSO else ()
        relinked = relink_textures(cand.model_path, roots, also)
    if relinked is None:
        return
    cand.staged = {cand.model_path.name: cand.model_path, **relinked.textures}
    cand.staged_texts = dict(relinked.materials)
    if relinked.model is not None:
        cand.staged_texts[cand.model_path.name] = relinked.model
    cand.warnings.extend(n for n in relinked.notes if n not in cand.warnings)


def _place_file(real: Path, target: Path) -> None:
    """``target`` the same file as ``real``: a hard link (a copy across file systems), renewed when
    ``real`` was replaced or, for a copy, changed."""
    if target.exists() and not target.is_symlink():
        try:
            if os.path.samefile(real, target):
                return
        except OSError:
            pass
        src, dst = real.stat(), target.stat()
        if target.stat().st_nlink == 1 and (src.st_size, src.st_mtime_ns) == (dst.st_size, dst.st_mtime_ns):
            return  # an up-to-date copy
    if target.is_symlink() or target.exists():
        target.unlink()
    try:
        os.link(real.resolve(), target)
    except OSError:
        shutil.copy2(real, target)


def stage(cand: Candidate, staging_root: Path) -> None:
    """Link ``cand.staged`` side by side under ``staging_root`` and point ``model_path`` at the link.

    Symbolic links (a copy where links are not allowed); a stale link is replaced. The folder name is
    a hash of (source, source_id), so reruns reuse it."""
    if cand.model_path is not None and not cand.staged and not cand.error:
        _relink(cand)
    if not cand.staged or cand.model_path is None or cand.error:
        return
    key = hashlib.sha256(f"{cand.source}\0{cand.source_id}".encode()).hexdigest()[:20]
    folder = staging_root / cand.source / key
    roots = cand.roots or LibraryRoots.of(cand.model_path.parent)
    for name, real in list(cand.staged.items()):  # never a link to, or a copy of, a file outside
        if not roots.contains(real) and name not in cand.staged_texts:
            del cand.staged[name]
            cand.warnings.append(f"{safe_text(name)} leads outside the library "
                                 f"({safe_text(os.path.realpath(real))}): not staged")
        elif not os.path.normpath(folder / name).startswith(os.path.normpath(folder) + os.sep):
            cand.error = f"cannot stage {safe_text(name)}: the name leaves the staging folder"
            return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for name, real in cand.staged.items():
            if name in cand.staged_texts:
                continue  # written below: a rewritten model or material
            link = folder / name
            link.parent.mkdir(parents=True, exist_ok=True)
            if cand.staged_texts:
                _place_file(real, link)  # trimesh refuses links that lead out of the model's folder
                continue
            if link.is_symlink() or link.exists():
                if link.is_symlink() and Path(os.readlink(link)) == real.resolve():
                    continue
                link.unlink()
            try:
                link.symlink_to(real.resolve())
            except OSError:
                shutil.copyfile(real, link)
        for name, text in cand.staged_texts.items():
            target = folder / name
            if target.is_symlink():
                target.unlink()
            data = text.encode() if isinstance(text, str) else text
            if not target.is_file() or target.read_bytes() != data:
                write_bytes_atomic(target, data)
    except OSError as exc:
        cand.error = f"cannot stage the model's files under {folder}: {exc.strerror or exc}"
        return
    cand.metadata["source_model_path"] = str(cand.model_path)
    cand.model_path = folder / cand.model_path.name
