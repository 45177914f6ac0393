"""A .blend file per converted asset: the worker's imported mesh, appended instead of re-imported (bpy).

``wm.usd_import`` of a capture-sized asset, plus joining its parts and the normals check, takes 0.5-1.1 s
in the worker (200k-786k faces); appending the finished mesh datablock from a .blend takes 0.06-0.13 s
compressed (zstd, about the size of the asset's .usdc) or 0.013-0.017 s uncompressed (about 3.5 x that
size). A scene uses several such assets and a dataset reuses each asset in many scenes, so the first
scene to use an asset imports it from USD and writes the file; every later scene, in any worker, appends
it (docs/performance.md has the figures, docs/blender.md the bpy facts).

Where: ``<asset folder>/_blend/<asset stem>-<digest>.blend``. The digest covers this module's
:data:`CACHE_VERSION`, Blender's version and the asset file's resolved path, size and modification time,
so a re-converted, moved or differently-built asset never meets a stale file (older files of the same
asset are removed when a new one is written). Images stay referenced by absolute path, as the USD import
made them. Writes go to a temporary name first and are renamed into place, so concurrent workers and
interrupted runs leave either the whole file or none. A file that cannot be read is treated as absent
(the asset is imported from USD and the file rewritten): the cache can only cost time, never a scene.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Optional

from mixcount.atomic import atomic_path
from mixcount.worker.contract import MESH_CACHE_MODES

CACHE_VERSION = 1  # bump when what the worker builds from an asset changes (join, normals fix, ...)
CACHE_DIR = "_blend"


def cache_file(asset: Path) -> Optional[Path]:
    """The .blend that holds ``asset``'s finished mesh (whether or not it exists yet); None when the
    asset file itself is missing (its import then fails with its own error)."""
    import bpy

    asset = Path(asset).resolve()
    try:
        st = asset.stat()
    except OSError:
        return None
    key = f"{CACHE_VERSION}|{bpy.app.version_string}|{asset}|{st.st_size}|{st.st_mtime_ns}"
    digest = hashlib.sha1(key.encode()).hexdigest()[:16]
    return asset.parent / CACHE_DIR / f"{asset.stem}-{digest}.blend"


def files_of(asset: Path) -> list[Path]:
    """Every cache file of ``asset``, whatever its digest (no bpy: callers outside the worker use it)."""
    folder, stem = Path(asset).parent / CACHE_DIR, Path(asset).stem
    return [f for f in folder.glob(f"{stem}-*.blend") if f.stem.rsplit("-", 1)[0] == stem]


def load(path: Path) -> Optional[Any]:
    """The mesh datablock appended from ``path`` (with its materials and images), or None when the file
    is missing or unreadable."""
    import bpy

    if not path.is_file():
        return None
    try:
        with bpy.data.libraries.load(str(path), link=False) as (src, dst):
            if len(src.meshes) != 1:
                return None
            dst.meshes = list(src.meshes)
        mesh = dst.meshes[0]
    except Exception:  # noqa: BLE001 - a truncated or foreign file is a cache miss
        return None
    if mesh is None or not len(mesh.polygons):
        return None
    return mesh


def store(mesh: Any, path: Path, mode: str) -> Optional[str]:
    """Write ``mesh`` (and what it uses) to ``path`` atomically; None, or why it could not be written.

    ``mode``: "zstd" (compressed) or "raw". Failing to write (a read-only asset folder, a full disk) is
    reported, not raised: the scene goes on with the mesh it already has."""
    import bpy

    if mode not in MESH_CACHE_MODES or mode == "off":
        raise ValueError(f"mesh cache mode must be zstd or raw, got {mode!r}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            bpy.data.libraries.write(str(tmp), {mesh}, fake_user=True, compress=(mode == "zstd"),
                                     path_remap="ABSOLUTE")
    except Exception as exc:  # noqa: BLE001 - the cache is an optimisation; the scene must not fail on it
        return f"{type(exc).__name__}: {exc}"
    asset = path.parent.parent / path.stem.rsplit("-", 1)[0]  # the suffix does not matter to files_of
    for old in files_of(asset):  # the same asset converted or placed differently before
        if old != path:
            try:
                old.unlink()
            except OSError:
                pass
    return None
