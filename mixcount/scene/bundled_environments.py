"""The HDRIs bundled with bpy: real captured light for scenes when no environment was ingested.

bpy 5.0 ships eight CC0 Poly Haven HDRIs by Greg Zaal as Blender's world studio lights
(``<bpy package>/5.0/datafiles/studiolights/world/*.exr``, 1k, with a ``license.txt`` naming each
original). They are found through bpy's install *without importing bpy* (``importlib.util.find_spec``
only locates the package; importing it would load all of Blender into the sampling process) and used
where they lie: nothing is copied into the repository or the dataset.

:func:`bundled_environments` gives them as :class:`~mixcount.scene.object_records.EnvironmentRecord` (no catalog
id, ``source="bpy_bundled"``); :func:`bundled_license` reads the ``license.txt`` beside one of them
into the fields ATTRIBUTION needs (licence, author, source, the original's URL).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import re
from pathlib import Path
from typing import Any, Optional

from mixcount.errors import ConfigError
from mixcount.scene.object_records import EnvironmentRecord

BUNDLED_SOURCE = "bpy_bundled"
WORLD_SUBDIR = ("datafiles", "studiolights", "world")
LICENSE_FILE = "license.txt"


def bpy_package_dir() -> Path:
    """The installed bpy package folder, located without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    if spec is None:
        raise ConfigError("scene.default_environment = \"bundled_hdri\" needs bpy installed (its bundled HDRIs); "
                          "install bpy or set scene.default_environment = \"sky\"")
    if spec.submodule_search_locations:
        return Path(list(spec.submodule_search_locations)[0])
    if spec.origin:
        return Path(spec.origin).parent
    raise ConfigError(f"cannot locate bpy's install folder (find_spec gave {spec!r})")


def _version_key(folder: Path) -> tuple[int, ...]:
    return tuple(int(p) for p in folder.name.split("."))


def bundled_hdri_dir(package_dir: Optional[Path] = None) -> Path:
    """``<bpy>/<version>/datafiles/studiolights/world`` (the newest version folder when several)."""
    root = Path(package_dir) if package_dir is not None else bpy_package_dir()
    found = sorted((v for v in root.iterdir() if re.fullmatch(r"\d+\.\d+", v.name) and v.joinpath(*WORLD_SUBDIR).is_dir()),
                   key=_version_key) if root.is_dir() else []
    if not found:
        raise ConfigError(f"no bundled HDRIs under {root} (looked for <version>/{'/'.join(WORLD_SUBDIR)}); "
                          "set scene.default_environment = \"sky\" or ingest HDRIs with `mixcount catalog ingest-env`")
    return found[-1].joinpath(*WORLD_SUBDIR)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    h.update(path.name.encode())
    h.update(path.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=4)
def _records(folder: str) -> tuple[EnvironmentRecord, ...]:
    maps = sorted(Path(folder).glob("*.exr"))
    if not maps:
        raise ConfigError(f"{folder}: no .exr HDRIs in bpy's studio-light folder")
    return tuple(EnvironmentRecord(environment_id=None, name=p.stem, path=str(p.resolve()), content_hash=_sha256(p),
                                   source=BUNDLED_SOURCE) for p in maps)


def bundled_environments(package_dir: Optional[Path] = None) -> tuple[EnvironmentRecord, ...]:
    """bpy's bundled HDRIs, sorted by file name (a fixed order: the sampler's index is reproducible)."""
    return _records(str(bundled_hdri_dir(package_dir)))


def is_bundled_path(path: str | Path) -> bool:
    """True for a path inside a ``<version>/datafiles/studiolights/world`` folder of a bpy install (also
    as a dataset records it, ``bpy:<version>/datafiles/...``: mixcount.dataset.package)."""
    text = str(path)
    parts = Path(text[len("bpy:"):] if text.startswith("bpy:") else text).parts
    return len(parts) >= 5 and tuple(parts[-4:-1]) == WORLD_SUBDIR and re.fullmatch(r"\d+\.\d+", parts[-5]) is not None


_ORIGINAL = re.compile(r"^-\s*(?P<name>[^:]+):\s*(?P<probably>probably\s+)?(?P<url>\S+)\s*$", re.I | re.M)


def parse_license(text: str) -> dict[str, Any]:
    """bpy's studio-light ``license.txt``: ``{"license", "author", "source", "source_url", "originals":
    {lower-case name: {"url", "uncertain"}}}`` (None where the text does not say)."""
    lic = re.search(r"licensed as ([A-Za-z0-9 .\-]+?)\.?\s*$", text, re.M)
    who = re.search(r"created by (?P<author>[^(\n]+?)\s*\((?P<source>[^)]*?)\s*(?P<url>https?://\S+?)?\)", text)
    originals = {m["name"].strip().lower(): {"url": m["url"], "uncertain": bool(m["probably"])}
                 for m in _ORIGINAL.finditer(text)}
    return {"license": lic.group(1).strip() if lic else None,
            "author": who["author"].strip() if who else None,
            "source": who["source"].strip() if who and who["source"].strip() else None,
            "source_url": who["url"] if who else None, "originals": originals}


def bundled_license(path: str | Path) -> Optional[dict[str, Any]]:
    """Attribution of one bundled HDRI from the ``license.txt`` beside it (or, when the dataset was made
    on another machine, the local bpy's): licence, author, source and the original's URL; None when no
    licence text is found."""
    path = Path(path)
    candidates = [path.parent / LICENSE_FILE]
    try:
        candidates.append(bundled_hdri_dir() / LICENSE_FILE)
    except ConfigError:
        pass
    text = next((c.read_text(encoding="utf-8") for c in candidates if c.is_file()), None)
    if text is None:
        return None
    info = parse_license(text)
    original = info.pop("originals").get(path.stem.lower(), {})
    return {**info, "name": path.stem, "original_url": original.get("url"),
            "original_uncertain": original.get("uncertain"), "license_text": text.strip()}
