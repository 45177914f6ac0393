"""``catalog ingest-env`` and ``catalog ingest-materials``: HDRIs and PBR texture sets for scenes.

Environments are HDR (Radiance) or OpenEXR latitude-longitude maps; a file is recognised by its magic
bytes, not its name. A PBR material set is a folder holding at least a base-colour map; the other
maps (roughness, normal, metallic, ao, displacement) are found by the usual name fragments
(``*_basecolor.png``, ``*_Color.jpg``, ``*_nor_gl.png``, ``*_rough.jpg`` ...). Both are keyed by content
hash, so re-ingesting is a no-op, and stored with absolute paths.

Each path named is a library: its files are read only inside it (``mixcount.library_root``; a link whose
target leaves it is refused and said, unless ``--allow-root`` / ``[ingest] extra_roots`` allow the
target's folder), and every map is decoded whole before it is recorded (``mixcount.catalog.media_check``):
one that does not decode is recorded ``broken`` with the reason and never drawn for a scene
(docs/ingest.md, "Decode before use").
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional

from mixcount.catalog.media_check import EXR_MAGIC, check_environment, check_texture
from mixcount.errors import CatalogError
from mixcount.library_root import LibraryRoots, OutsideLibraryError

ENV_EXTENSIONS = (".hdr", ".exr")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
MAP_PATTERNS = (  # first match wins; order matters ("normal" before "color" in "normalcolor" names)
    ("normal", re.compile(r"(normal|nor_gl|nor_dx|_nrm|_nor\b|_n\b)", re.I)),
    ("roughness", re.compile(r"(rough|_rgh)", re.I)),
    ("metallic", re.compile(r"(metal|_mtl)", re.I)),
    ("ao", re.compile(r"(ambientocclusion|_ao\b|occlusion)", re.I)),
    ("displacement", re.compile(r"(displacement|_disp|height|bump)", re.I)),
    ("base_color", re.compile(r"(basecolor|base_color|albedo|diffuse|_diff\b|_col\b|color|colour)", re.I)),
)


@dataclass
class IngestAssetsSummary:
    """What one ``ingest-env`` / ``ingest-materials`` run did: ``broken`` are (path, reason) of the files
    recorded but never drawn (they did not decode whole), ``refused`` the links that lead outside the
    library (not read, not recorded), ``skipped`` what is no environment map or material set."""

    new: int = 0
    unchanged: int = 0
    skipped: list[str] = field(default_factory=list)
    broken: list[tuple[str, str]] = field(default_factory=list)
    refused: list[tuple[str, str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"new": self.new, "unchanged": self.unchanged, "skipped": self.skipped,
                "broken": [{"path": p, "reason": r} for p, r in self.broken],
                "refused": [{"path": p, "reason": r} for p, r in self.refused]}


def _sha256(paths: Iterable[Path]) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(p.name.encode())
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def is_environment_map(path: Path) -> bool:
    """True for a Radiance HDR or OpenEXR file (by magic bytes)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(10)
    except OSError:
        return False
    return head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE") or head[:4] == EXR_MAGIC


def _library_folders(named: Path, roots: LibraryRoots, summary: IngestAssetsSummary) -> Iterator[tuple[Path, list[Path]]]:
    """(real folder, its real files) for ``named`` and every folder below it, each real folder once (loops
    and repeated link targets walked once). A link whose target leaves ``roots`` is refused and said in
    ``summary.refused``, never followed or read."""
    seen: set[str] = set()
    stack = [roots.check(named, "the folder named")]
    while stack:
        folder = stack.pop()
        if str(folder) in seen:
            continue
        seen.add(str(folder))
        try:
            entries = sorted(os.scandir(folder), key=lambda e: e.name)
        except OSError as exc:
            summary.skipped.append(f"{folder}: cannot list ({exc.strerror or exc})")
            continue
        files, subdirs = [], []
        for entry in entries:
            if entry.is_symlink():
                try:
                    roots.check(entry.path, "link")
                except OutsideLibraryError as exc:
                    summary.refused.append((entry.path, exc.reason))
                    continue
            real = Path(os.path.realpath(entry.path))
            if entry.is_dir():
                subdirs.append(real)
            elif entry.is_file():
                files.append(real)
        yield folder, files
        stack.extend(reversed(subdirs))


def _library_files(paths: Iterable[Path], exts: tuple[str, ...], extra_roots: Iterable[str],
                   summary: IngestAssetsSummary) -> list[Path]:
    """The real files with one of ``exts`` under ``paths`` (each path named is its own library), once each."""
    out: dict[str, Path] = {}
    for p in paths:
        p = Path(p).expanduser()
        if not p.exists():
            raise CatalogError(f"path {p} does not exist")
        roots = LibraryRoots.of(p, extra_roots)
        if p.is_file():
            real = roots.check(p, "file")
            out.setdefault(str(real), real)
            continue
        for _, files in _library_folders(p, roots, summary):
            for f in files:
                if f.suffix.lower() in exts:
                    out.setdefault(str(f), f)
    return list(out.values())


def _record_check(row: Any, reason: Optional[str], path: Path, summary: IngestAssetsSummary) -> None:
    from mixcount.catalog.models import utcnow

    row.broken, row.checked_at = reason, utcnow()
    if reason:
        summary.broken.append((str(path), reason))


def ingest_environments(catalog: Any, paths: Iterable[Path], *, max_pixels: int,
                        extra_roots: Iterable[str]) -> IngestAssetsSummary:
    """Store every HDR/EXR map under ``paths`` in table ``environments``, each decoded whole first: one that
    does not decode (or holds NaN, or is black) is stored ``broken`` with the reason and never drawn. A
    row from before the check is decoded at its next ingest."""
    from sqlalchemy import select

    from mixcount.catalog.models import Environment

    summary = IngestAssetsSummary()
    files = _library_files(paths, ENV_EXTENSIONS, extra_roots, summary)
    with catalog.session() as session:
        known = {e.content_hash: e for e in session.execute(select(Environment)).scalars()}
        for path in files:
            if not is_environment_map(path):
                empty = path.stat().st_size == 0
                summary.skipped.append(f"{path}: {'an empty file' if empty else 'not an HDR or EXR file'}")
                continue
            digest = _sha256([path])
            row = known.get(digest)
            if row is not None and row.checked_at is not None:
                summary.unchanged += 1
                if row.broken:
                    summary.broken.append((str(path), row.broken))
                continue
            if row is None:
                row = Environment(name=path.stem, path=str(path), content_hash=digest)
                session.add(row)
                known[digest] = row
                summary.new += 1
            else:
                summary.unchanged += 1
            _record_check(row, check_environment(path, max_pixels), path, summary)
        session.commit()
    return summary


def classify_maps(folder: Path, files: Optional[Iterable[Path]] = None) -> dict[str, Path]:
    """Map kind -> file for the images directly in ``folder`` (or among ``files``; first file per kind,
    sorted by name)."""
    listed = sorted(files, key=lambda f: f.name) if files is not None else sorted(folder.iterdir())
    maps: dict[str, Path] = {}
    for f in listed:
        if not f.is_file() or f.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        for kind, pattern in MAP_PATTERNS:
            if pattern.search(f.stem):
                maps.setdefault(kind, f.resolve())
                break
    return maps


def _material_sets(paths: Iterable[Path], extra_roots: Iterable[str],
                   summary: IngestAssetsSummary) -> list[tuple[Path, dict[str, Path]]]:
    out: dict[str, tuple[Path, dict[str, Path]]] = {}
    for p in paths:
        p = Path(p).expanduser()
        if not p.is_dir():
            raise CatalogError(f"material path {p} is not a folder")
        roots = LibraryRoots.of(p, extra_roots)
        for folder, files in _library_folders(p, roots, summary):
            maps = classify_maps(folder, files)
            if maps:
                out.setdefault(str(folder), (folder, maps))
    return list(out.values())


def _maps_reason(maps: dict[str, Path], max_pixels: int) -> Optional[str]:
    """Why a material set cannot be used: the first of its maps that does not decode whole, or None."""
    for kind in sorted(maps):
        reason = check_texture(maps[kind], max_pixels)
        if reason:
            return f"{kind} map {maps[kind].name}: {reason}"
    return None


def ingest_materials(catalog: Any, paths: Iterable[Path], *, max_pixels: int,
                     extra_roots: Iterable[str]) -> IngestAssetsSummary:
    """Store every folder under ``paths`` that holds a PBR set (at least a base-colour map), every map
    decoded whole first: a set with a map that does not decode is stored ``broken`` and never drawn."""
    from sqlalchemy import select

    from mixcount.catalog.models import Material

    summary = IngestAssetsSummary()
    sets = _material_sets(paths, extra_roots, summary)
    with catalog.session() as session:
        known = {m.content_hash: m for m in session.execute(select(Material)).scalars()}
        for folder, maps in sets:
            if "base_color" not in maps:
                summary.skipped.append(f"{folder}: no base-colour map among {sorted(maps)}")
                continue
            digest = _sha256([maps[k] for k in sorted(maps)])
            row = known.get(digest)
            if row is not None and row.checked_at is not None:
                summary.unchanged += 1
                if row.broken:
                    summary.broken.append((str(folder), row.broken))
                continue
            if row is None:
                row = Material(name=folder.name, path=str(folder), content_hash=digest,
                               maps_json=json.dumps({k: str(v) for k, v in sorted(maps.items())}))
                session.add(row)
                known[digest] = row
                summary.new += 1
            else:
                summary.unchanged += 1
            _record_check(row, _maps_reason(maps, max_pixels), folder, summary)
        session.commit()
    return summary
