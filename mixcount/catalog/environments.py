"""``catalog ingest-env`` and ``catalog ingest-materials``: HDRIs and PBR texture sets for scenes.

Environments are HDR (Radiance) or OpenEXR latitude-longitude maps; a file is recognised by its magic
bytes, not its name. A PBR material set is a folder holding at least a base-colour map; the other
maps (roughness, normal, metallic, ao, displacement) are found by the usual name fragments
(``*_basecolor.png``, ``*_Color.jpg``, ``*_nor_gl.png``, ``*_rough.jpg`` ...). Both are keyed by content
hash, so re-ingesting is a no-op, and stored with absolute paths.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from mixcount.errors import CatalogError

ENV_EXTENSIONS = (".hdr", ".exr")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff")
EXR_MAGIC = b"\x76\x2f\x31\x01"
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
    new: int = 0
    unchanged: int = 0
    skipped: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"new": self.new, "unchanged": self.unchanged, "skipped": self.skipped}


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


def _walk(paths: Iterable[Path], exts: tuple[str, ...]) -> list[Path]:
    out: list[Path] = []
    for p in paths:
        p = Path(p).expanduser()
        if not p.exists():
            raise CatalogError(f"path {p} does not exist")
        if p.is_file():
            out.append(p.resolve())
        else:
            out.extend(sorted(q.resolve() for q in p.rglob("*") if q.is_file() and q.suffix.lower() in exts))
    return out


def ingest_environments(catalog: Any, paths: Iterable[Path]) -> IngestAssetsSummary:
    """Store every HDR/EXR map under ``paths`` in table ``environments``."""
    from sqlalchemy import select

    from mixcount.catalog.models import Environment

    summary = IngestAssetsSummary()
    with catalog.session() as session:
        known = set(session.execute(select(Environment.content_hash)).scalars())
        for path in _walk(paths, ENV_EXTENSIONS):
            if not is_environment_map(path):
                summary.skipped.append(f"{path}: not an HDR or EXR file")
                continue
            digest = _sha256([path])
            if digest in known:
                summary.unchanged += 1
                continue
            session.add(Environment(name=path.stem, path=str(path), content_hash=digest))
            known.add(digest)
            summary.new += 1
        session.commit()
    return summary


def classify_maps(folder: Path) -> dict[str, Path]:
    """Map kind -> file for the images directly in ``folder`` (first file per kind, sorted by name)."""
    maps: dict[str, Path] = {}
    for f in sorted(folder.iterdir()):
        if not f.is_file() or f.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        for kind, pattern in MAP_PATTERNS:
            if pattern.search(f.stem):
                maps.setdefault(kind, f.resolve())
                break
    return maps


def ingest_materials(catalog: Any, paths: Iterable[Path]) -> IngestAssetsSummary:
    """Store every folder under ``paths`` that holds a PBR set (at least a base-colour map)."""
    from sqlalchemy import select

    from mixcount.catalog.models import Material

    summary = IngestAssetsSummary()
    folders: list[Path] = []
    for p in paths:
        p = Path(p).expanduser()
        if not p.is_dir():
            raise CatalogError(f"material path {p} is not a folder")
        folders.extend([p.resolve()] + sorted(q.resolve() for q in p.rglob("*") if q.is_dir()))
    with catalog.session() as session:
        known = set(session.execute(select(Material.content_hash)).scalars())
        for folder in folders:
            maps = classify_maps(folder)
            if not maps:
                continue
            if "base_color" not in maps:
                summary.skipped.append(f"{folder}: no base-colour map among {sorted(maps)}")
                continue
            digest = _sha256([maps[k] for k in sorted(maps)])
            if digest in known:
                summary.unchanged += 1
                continue
            session.add(Material(name=folder.name, path=str(folder), content_hash=digest,
                                 maps_json=json.dumps({k: str(v) for k, v in sorted(maps.items())})))
            known.add(digest)
            summary.new += 1
        session.commit()
    return summary
