"""Paths that travel: how a stage and a scene's records name files without any absolute path
(docs/usd.md, "Portable datasets"; the packaging step is :mod:`mixcount.dataset.package`).

The files a dataset's stages use are entries of ``OUT/assets/`` (converted assets ``<hash>.usdc`` with
``<hash>_tex/`` and ``<hash>_collision.usdc``, ``environments/<file>``, ``materials/<digest>/<file>``),
referenced relative to the stage (``@../../assets/<hash>.usdc@``). While composing each entry is a relative
symbolic link to the catalog's file (:func:`link_into_dataset`; bpy's bundled HDRIs are hard-linked or
copied).

Recorded paths (metadata.json, the spec in each stage's customLayerData) go through :func:`portable_paths`:
a path inside OUT becomes relative to OUT, a catalog asset ``assets/<name>``, a file of bpy's install
``bpy:<path in the bpy package>`` (:func:`resolve_bpy_path` gives it back on any machine with bpy), and any
other file (a source model, a proxy) ``source:<file name>`` - the object is named by its catalog id and
content hash beside it.
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from mixcount.atomic import atomic_path
from mixcount.errors import DatasetError

ASSETS_DIR = "assets"
ENVIRONMENTS_DIR = "environments"
MATERIALS_DIR = "materials"
SOURCES_DIR = "sources"
BPY_PREFIX = "bpy:"
SOURCE_PREFIX = "source:"


# ------------------------------------------------------------------------------------ links while composing


def _same_target(link: Path, src: Path) -> bool:
    try:
        return link.resolve() == src.resolve()
    except OSError:
        return False


def link_into_dataset(out_dir: Path, src: Path, rel: str) -> Path:
    """``OUT/assets/<rel>`` as a relative symbolic link to ``src`` (created atomically; kept when it is
    already there: a link to the same file, or a packaged copy); returns the entry's path.

    A file of bpy's install (a bundled HDRI, a few MB) is hard-linked or copied instead: a relative link
    from the dataset into the Python environment would spell out this machine's folders."""
    dest = Path(out_dir) / ASSETS_DIR / rel
    if dest.is_symlink() and _same_target(dest, src):
        return dest
    if dest.exists() and not dest.is_symlink():
        return dest  # packaged (or bpy's file, copied): a real file stays
    dest.parent.mkdir(parents=True, exist_ok=True)
    real = Path(src).resolve()
    bpy = bpy_dir()
    with atomic_path(dest) as tmp:
        if bpy is not None and bpy in real.parents:
            try:
                os.link(real, tmp)
            except OSError:  # another file system
                try:
                    shutil.copyfile(real, tmp)
                except OSError as exc:  # named by the dataset's file: a full disk is the output's, not bpy's
                    raise OSError(exc.errno, exc.strerror, str(dest)) from exc
        else:
            os.symlink(os.path.relpath(real, dest.parent.resolve()), tmp)
    return dest


def stage_reference(out_dir: Path, stage_dir: Path, rel: str) -> str:
    """The asset path a stage in ``stage_dir`` writes for ``OUT/assets/<rel>`` (relative, posix)."""
    dest = (Path(out_dir) / ASSETS_DIR / rel).absolute()
    ref = Path(os.path.relpath(dest, Path(stage_dir).absolute())).as_posix()
    return ref if ref.startswith("../") else f"./{ref}"


def environment_entry(path: str | Path) -> str:
    """``environments/<file>`` for an environment map (file names of ingested maps and bpy's are unique
    within a dataset's catalog: a clash gets the file's digest in its name)."""
    p = Path(path)
    return f"{ENVIRONMENTS_DIR}/{p.name}"


def material_entry(path: str | Path) -> str:
    """``materials/<digest of the folder>/<file>`` for a floor texture map."""
    p = Path(path).resolve()
    digest = hashlib.sha256(str(p.parent).encode()).hexdigest()[:12]
    return f"{MATERIALS_DIR}/{digest}/{p.name}"


# ------------------------------------------------------------------------------------ recorded paths


@functools.lru_cache(maxsize=1)
def bpy_dir() -> Optional[Path]:
    """bpy's package folder (found without importing bpy), or None without bpy."""
    try:
        from mixcount.scene.bundled_environments import bpy_package_dir

        return bpy_package_dir().resolve()
    except Exception:
        return None


def resolve_bpy_path(ref: str) -> Path:
    """``bpy:<path>`` -> that file of this machine's bpy install."""
    if not ref.startswith(BPY_PREFIX):
        raise ValueError(f"{ref!r} is not a {BPY_PREFIX} reference")
    root = bpy_dir()
    if root is None:
        raise DatasetError(f"{ref} names a file of bpy's install, and bpy is not installed here")
    return root / ref[len(BPY_PREFIX):].lstrip("/")


@dataclass
class PathRoots:
    """Where the absolute paths of one dataset's records come from, and what each becomes."""

    out_dir: Path
    assets_dirs: tuple[Path, ...] = ()  # the catalog's usd_assets folders -> "assets/<rel>"
    bpy: Optional[Path] = field(default_factory=bpy_dir)

    def rewrite(self, text: str) -> str:
        if not _is_file_path(text):
            return text  # not a path of this machine's file system (a USD prim path "/World/...", text)
        p = Path(text)
        for root in _variants(self.out_dir):
            if _under(p, root):
                return p.relative_to(root).as_posix()
        for root in (r for d in self.assets_dirs for r in _variants(d)):
            if _under(p, root):
                return f"{ASSETS_DIR}/{p.relative_to(root).as_posix()}"
        if self.bpy is not None:
            for root in _variants(self.bpy):
                if _under(p, root):
                    return f"{BPY_PREFIX}{p.relative_to(root).as_posix()}"
        return f"{SOURCE_PREFIX}{p.name}"


@functools.lru_cache(maxsize=1)
def _top_level() -> frozenset[str]:
    try:
        return frozenset(os.listdir("/"))
    except OSError:
        return frozenset()


def _is_file_path(text: str) -> bool:
    """An absolute path whose top folder exists here ("/tmp/...", "/home/..."); USD prim paths
    ("/World/Objects/obj_0001") and other text are left alone."""
    if not text.startswith("/") or text.startswith("//") or "\n" in text or len(text) > 4096:
        return False
    top = text[1:].split("/", 1)[0]
    return bool(top) and top in _top_level()


def _variants(root: Path) -> list[Path]:
    root = Path(root).absolute()
    out = [root]
    try:
        real = root.resolve()
        if real != root:
            out.append(real)
    except OSError:
        pass
    return out


def _under(p: Path, root: Path) -> bool:
    return p == root or root in p.parents


def portable_paths(obj: Any, roots: PathRoots) -> Any:
    """``obj`` (JSON-like) with every absolute path - values and keys - rewritten by ``roots``."""
    if isinstance(obj, str):
        return roots.rewrite(obj)
    if isinstance(obj, dict):
        return {roots.rewrite(k) if isinstance(k, str) else k: portable_paths(v, roots) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [portable_paths(v, roots) for v in obj]
    return obj
