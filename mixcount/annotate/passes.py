"""Compact, standard files for the depth and normal passes, and their loaders (numpy, Pillow, OpenEXR).

Formats (``compose.depth_format`` / ``compose.normal_format``; see docs/performance.md for the measured
sizes and precision):

* depth ``png16`` (default): ``depth.png``, 16-bit greyscale; metres = value x unit, 0 = no surface. The
  unit is the smallest of 0.1, 0.2, 0.5, 1, 2, 5, 10 mm that fits the scene's farthest surface in 65535
  steps; it is stored in the PNG's ``tEXt`` chunk ``mixcount:depth_unit_m`` and in metadata.json
  (``passes.depth.unit_m``). Rounding to the nearest step: the error is at most half a unit.
* depth ``exr32``: ``depth.exr``, one 32-bit float channel ``Z`` with lossless ZIP compression; exact.
* normal ``png8`` (default): ``normal.png``, 8-bit RGB; n = value / 255 x 2 - 1 per axis, renormalised,
  camera space (x right, y up, z towards the camera); (0, 0, 0) = no surface (no unit vector encodes to
  it). Worst angular error about 0.4 degrees.
* normal ``exr16``: ``normal.exr``, half-float ``R``, ``G``, ``B`` with ZIP; error about 0.03 degrees.
* ``npy`` (either pass): the float32 arrays as before (``depth.npy``, ``normal.npy``): exact and large.

:func:`read_depth` and :func:`read_normals` read every format, including datasets written before the
compact formats existed (``.npy``), from a file or from a scene folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from mixcount.atomic import atomic_path

# re-exported: the passes `compose --passes` chooses from (rgb is always written)
from mixcount.config import PASSES as PASSES

DEPTH_FORMATS = {"png16": "depth.png", "exr32": "depth.exr", "npy": "depth.npy"}
NORMAL_FORMATS = {"png8": "normal.png", "exr16": "normal.exr", "npy": "normal.npy"}
DEPTH_UNITS_M = (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2)
DEPTH_UNIT_KEY = "mixcount:depth_unit_m"


def parse_passes(value: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"depth,normal"`` or a list -> a checked tuple in canonical order; ValueError names a bad pass."""
    items = [p.strip().lower() for p in (value.split(",") if isinstance(value, str) else value) if p.strip()]
    bad = sorted(set(items) - set(PASSES))
    if bad:
        raise ValueError(f"unknown pass(es) {', '.join(bad)}: choose from {', '.join(PASSES)} (rgb is always written)")
    return tuple(p for p in PASSES if p in items)


def depth_unit(max_depth_m: float) -> float:
    """The smallest unit of :data:`DEPTH_UNITS_M` that stores ``max_depth_m`` in 16 bits."""
    for unit in DEPTH_UNITS_M:
        if max_depth_m / unit <= 65535:
            return unit
    raise ValueError(f"depth {max_depth_m:.1f} m does not fit a 16-bit PNG at 1 cm steps: use depth_format exr32")


def _atomic(path: Path, write: Callable[[Path], object]) -> None:
    with atomic_path(path) as tmp:
        write(tmp)


def _write_exr(path: Path, channels: dict[str, NDArray[Any]]) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    _atomic(path, lambda p: OpenEXR.File(header, channels).write(str(p)))


def _read_exr(path: Path) -> dict[str, NDArray[Any]]:
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {name: np.array(ch.pixels) for name, ch in f.channels().items()}


def suffixed(name: str, suffix: str) -> str:
    """``depth.png`` + ``_cam_1`` -> ``depth_cam_1.png``: the file of a scene's further cameras."""
    stem, dot, ext = name.partition(".")
    return f"{stem}{suffix}{dot}{ext}"


def write_depth(folder: Path, depth: NDArray[Any], fmt: str, suffix: str = "") -> dict[str, object]:
    """Write planar depth (H, W) metres, 0 = none, into ``folder`` (file name + ``suffix`` for a further
    camera); returns its metadata record."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    folder = Path(folder)
    d = np.asarray(depth, dtype=np.float32)
    name = suffixed(DEPTH_FORMATS[fmt], suffix)
    if fmt == "npy":
        np.save(folder / name, d)
        return {"file": name, "format": "npy", "dtype": "float32", "units": "m"}
    if fmt == "exr32":
        _write_exr(folder / name, {"Z": d})
        return {"file": name, "format": "exr32", "channel": "Z", "compression": "zip", "units": "m"}
    unit = depth_unit(float(d.max()) if d.size else 0.0)
    q = np.rint(d / unit).astype(np.uint16)
    q[(d > 0) & (q == 0)] = 1  # a surface closer than half a unit stays a surface
    info = PngInfo()
    info.add_text(DEPTH_UNIT_KEY, repr(unit))
    _atomic(folder / name, lambda p: Image.fromarray(q).save(p, format="PNG", pnginfo=info))
    return {"file": name, "format": "png16", "unit_m": unit, "max_error_m": unit / 2}


def write_normals(folder: Path, normals: NDArray[Any], fmt: str, suffix: str = "") -> dict[str, object]:
    """Write camera-space unit normals (H, W, 3), 0 = none, into ``folder`` (file name + ``suffix`` for a
    further camera); returns its metadata record."""
    from PIL import Image

    folder = Path(folder)
    n = np.asarray(normals, dtype=np.float32)
    name = suffixed(NORMAL_FORMATS[fmt], suffix)
    if fmt == "npy":
        np.save(folder / name, n)
        return {"file": name, "format": "npy", "dtype": "float32"}
    if fmt == "exr16":
        _write_exr(folder / name, {"R": n[..., 0].astype(np.float16), "G": n[..., 1].astype(np.float16),
                                   "B": n[..., 2].astype(np.float16)})
        return {"file": name, "format": "exr16", "compression": "zip"}
    none = ~np.any(n != 0, axis=-1)
    q = np.clip(np.rint((np.clip(n, -1.0, 1.0) + 1.0) * 127.5), 0, 255).astype(np.uint8)
    q[none] = 0
    _atomic(folder / name, lambda p: Image.fromarray(q, mode="RGB").save(p, format="PNG"))
    return {"file": name, "format": "png8", "encoding": "n = v / 255 * 2 - 1, renormalised; (0,0,0) = none"}


def _find(path: Path, names: dict[str, str]) -> Path:
    path = Path(path)
    if path.is_dir():
        for name in names.values():
            if (path / name).is_file():
                return path / name
        raise FileNotFoundError(f"no {' / '.join(names.values())} in {path}")
    return path


def read_depth(path: str | Path, unit_m: Optional[float] = None) -> NDArray[Any]:
    """Planar depth in metres, float32 (H, W), 0 = no surface, from depth.png / depth.exr / depth.npy
    (or a scene folder holding one). ``unit_m`` overrides the PNG's stored unit."""
    p = _find(Path(path), DEPTH_FORMATS)
    if p.suffix == ".npy":
        return np.asarray(np.load(p), dtype=np.float32)
    if p.suffix == ".exr":
        ch = _read_exr(p)
        return np.asarray(ch["Z"] if "Z" in ch else next(iter(ch.values())), dtype=np.float32)
    from PIL import Image

    with Image.open(p) as im:
        if unit_m is None:
            text = getattr(im, "text", {}) or {}
            unit_m = float(text.get(DEPTH_UNIT_KEY, 1e-3))
        q = np.array(im).astype(np.float32)
    return (q * np.float32(unit_m)).astype(np.float32)


def read_normals(path: str | Path) -> NDArray[Any]:
    """Camera-space unit normals, float32 (H, W, 3), 0 = no surface, from normal.png / normal.exr /
    normal.npy (or a scene folder holding one)."""
    p = _find(Path(path), NORMAL_FORMATS)
    if p.suffix == ".npy":
        return np.asarray(np.load(p), dtype=np.float32)
    if p.suffix == ".exr":
        ch = _read_exr(p)
        return np.stack([np.asarray(ch[c], dtype=np.float32) for c in ("R", "G", "B")], axis=-1)
    from PIL import Image

    with Image.open(p) as im:
        q = np.array(im.convert("RGB"))
    none = ~np.any(q != 0, axis=-1)
    n = q.astype(np.float32) / np.float32(127.5) - np.float32(1.0)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), np.float32(1e-6))
    n[none] = 0.0
    return n
