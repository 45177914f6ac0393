"""Every file a USD stage needs, and the first one that is missing, before anything renders (issue 60).

A stage names files in three ways: layers it composes (sublayers, references, payloads: the dataset's
``../../assets/<hash>.usdc``, a wrapped USD source), and asset-valued attributes (a floor texture
``./textures/floor_dots.png``, a dome light's environment map, an asset's ``<hash>_tex/basecolor_0.png``).
Blender renders a texture it cannot find in flat magenta and says nothing; a reference it cannot open
is an object that is simply not there. So compose, ``mixcount render`` and the worker ask
:func:`missing_files` first and stop with one line naming the file (:func:`require_files`).

The walk reads each layer with ``UsdUtils.ExtractExternalReferences`` (no composition, no warnings on
stderr: ``UsdUtils.ComputeAllDependencies`` would print one per unresolved path), resolves each path
as USD's default resolver does for a layer-relative path (against the referring layer's folder), and
follows every referenced layer once. Paths with UDIM / ``<...>`` tokens are left alone.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

from mixcount.errors import AssetError

LAYER_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")
IMAGE_MAGIC = {".png": b"\x89PNG", ".jpg": b"\xff\xd8", ".jpeg": b"\xff\xd8"}


@dataclass(frozen=True)
class Dependency:
    """One path a layer names: the layer, the path as written, where it resolves, and whether it is a layer."""

    layer: Path
    written: str
    path: Path
    is_layer: bool


def _resolve(layer: Path, written: str) -> Path:
    """Lexically, as USD's default resolver does (TfNormPath): a link keeps its own name."""
    return Path(os.path.normpath(layer.parent / written))


def _named_by(layer: Path) -> list[str]:
    from pxr import UsdUtils

    sublayers, references, payloads = UsdUtils.ExtractExternalReferences(str(layer))
    return [str(p) for p in (*sublayers, *references, *payloads) if str(p)]


def dependencies(stage_path: Path) -> Iterator[Dependency]:
    """Every path the stage's layers name, depth first, each layer read once (a layer that cannot be
    read is reported by :func:`missing_files`, not followed)."""
    root = Path(os.path.abspath(stage_path))
    seen = {root}
    todo = [root]
    while todo:
        layer = todo.pop()
        for written in _named_by(layer):
            if "<" in written or written.startswith(("http:", "https:")):
                continue  # UDIM / templated paths and URLs: another resolver's business
            path = _resolve(layer, written)
            is_layer = path.suffix.lower() in LAYER_EXTENSIONS
            yield Dependency(layer, written, path, is_layer)
            if is_layer and path not in seen and path.suffix.lower() != ".usdz" and path.is_file():
                seen.add(path)
                todo.append(path)


def why_unusable(path: Path) -> Optional[str]:
    """None when ``path`` is a file that can be read (and, for PNG / JPEG, starts like one), else why not."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except FileNotFoundError:
        link = next((p for p in (path, *path.parents) if p.is_symlink() and not p.exists()), None)
        if link is None:
            return "missing"
        where = "a broken link" if link == path else f"missing (its folder {link} is a broken link)"
        return (f"{where} to {os.readlink(link)} (moved without its assets? `mixcount package` writes a "
                "copy that holds them)")
    except IsADirectoryError:
        return "a folder, not a file"
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    if not head:
        return "empty"
    magic = IMAGE_MAGIC.get(path.suffix.lower())
    if magic is not None and not head.startswith(magic):
        return f"not a {path.suffix.lower().lstrip('.').upper()} image"
    return None


def missing_files(stage_path: Path) -> list[tuple[Dependency, str]]:
    """Each dependency of the stage that cannot be used, with why (missing, empty, not an image...)."""
    out = []
    checked: dict[Path, Optional[str]] = {}
    for dep in dependencies(stage_path):
        if dep.path not in checked:
            checked[dep.path] = why_unusable(dep.path)
            if checked[dep.path] is not None:
                out.append((dep, str(checked[dep.path])))
    return out


def problem_line(stage_path: Path) -> Optional[str]:
    """One line naming the first unusable file of the stage (and how many more), or None."""
    bad = missing_files(stage_path)
    if not bad:
        return None
    dep, why = bad[0]
    kind = "layer" if dep.is_layer else "file"
    more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
    return f"{kind} {dep.path} is {why}: {dep.layer.name} names it as {dep.written!r}{more}"


def require_files(stage_path: Path, what: str) -> None:
    """Raise AssetError (one line: ``what``, the file, why, which layer names it) when a file the stage
    needs cannot be used; nothing is rendered then."""
    line = problem_line(stage_path)
    if line is not None:
        raise AssetError(f"{what}: {line}")
