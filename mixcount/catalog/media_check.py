"""Decode before use: every image a render will read is decoded once, whole, when it enters the catalog.

A texture, a floor map or an environment map that is truncated, lies about its size or declares more
pixels than ``[ingest] max_image_pixels`` renders wrong without a word (Blender paints an image it cannot
read magenta and an environment it cannot read black), so ingest decodes each one here and records the
reason it did not decode (docs/ingest.md, "Decode before use"):

- PNG / JPEG / TIFF / ... through Pillow, with ``Image.MAX_IMAGE_PIXELS`` set from the config and Pillow's
  decompression-bomb warning turned into a refusal; the declared size is tested before any pixel is
  decoded, then the whole image is decoded (``load``) and its chunks' checksums verified (``verify``).
- OpenEXR through the ``OpenEXR`` package (a declared dependency): the header first (its data window
  against the pixel limit), then every channel. The library prints its own complaints on the C stderr;
  they are caught and become part of the reason.
- Radiance HDR (RGBE) through :func:`read_radiance`, a numpy reader of the format (header, resolution line,
  flat or run-length-encoded scanlines): nothing in the environment reads it without Blender, and bpy
  may only run inside the engine's worker processes.

An environment map must also light a scene: one whose pixels are all black, or hold NaN / infinite
values (which Cycles turns into a black or speckled render), is refused too (:func:`check_environment`).

:func:`render_fault` is the same idea at the other end: a rendered RGB image that is black, or Blender's
missing-texture magenta, where the inputs were checked whole is a failed render, not a written one.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

import numpy as np
from numpy.typing import NDArray

EXR_MAGIC = b"\x76\x2f\x31\x01"
RADIANCE_MAGICS = (b"#?RADIANCE", b"#?RGBE")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".tga", ".webp", ".gif", ".exr", ".hdr")
LIMIT_KEY = "[ingest] max_image_pixels"
# a render is black when its mean is below this (0-255): the damaged environment of issue 68 gave 0.1
BLACK_MEAN = 1.0
# Blender's missing-image colour is (1, 0, 1): shaded, red and blue stay equal and green stays near zero
MAGENTA_SHARE_SCENE = 0.25  # of a scene's pixels (a floor or the world behind the scene)
MAGENTA_SHARE_OBJECT = 0.5  # of a canonical render's object pixels (its mask)


@dataclass(frozen=True)
class Decoded:
    """What decoding one file found: its kind, its size, and for HDR / EXR the pixel statistics that
    tell whether it can light a scene (``mean`` of the RGB values, ``non_finite`` NaN / inf samples)."""

    kind: str
    width: int
    height: int
    mean: float = 0.0
    peak: float = 0.0
    non_finite: int = 0


class MediaRefused(ValueError):
    """A file that does not decode whole (internal to this module: the public functions return reasons)."""


def _magic(path: Path) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(16)


def _over_limit(width: int, height: int, max_pixels: int) -> Optional[str]:
    if width <= 0 or height <= 0:
        return f"declares an empty image ({width} x {height} pixels)"
    if width * height > max_pixels:
        return (f"declares {width} x {height} pixels ({width * height:,}), over the limit of {max_pixels:,} "
                f"({LIMIT_KEY}); not decoded")
    return None


@contextlib.contextmanager
def _pil_limits(max_pixels: int) -> Iterator[None]:
    """Pillow's bomb check at ``max_pixels`` (its warning an error) and truncated images refused."""
    from PIL import Image, ImageFile

    old = (Image.MAX_IMAGE_PIXELS, ImageFile.LOAD_TRUNCATED_IMAGES)
    Image.MAX_IMAGE_PIXELS, ImageFile.LOAD_TRUNCATED_IMAGES = max_pixels, False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    finally:
        Image.MAX_IMAGE_PIXELS, ImageFile.LOAD_TRUNCATED_IMAGES = old


def _decode_pil(path: Path, max_pixels: int) -> Decoded:
    from PIL import Image, UnidentifiedImageError

    kind = "image"
    with _pil_limits(max_pixels):
        try:
            with Image.open(path) as im:
                kind, (w, h) = str(im.format or "image").lower(), im.size
                over = _over_limit(w, h, max_pixels)
                if over:
                    raise MediaRefused(over)
                im.load()
            with Image.open(path) as im:
                im.verify()
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            found = re.search(r"\((\d+) pixels\)", str(exc))
            size = f"declares {int(found.group(1)):,} pixels, " if found else ""
            raise MediaRefused(f"{size}over the limit of {max_pixels:,} ({LIMIT_KEY}); not decoded "
                               "(Pillow's decompression-bomb check)") from None
        except UnidentifiedImageError:
            raise MediaRefused("not an image Pillow can read (unknown or damaged header)") from None
        except (OSError, SyntaxError, ValueError, EOFError, IndexError, MemoryError) as exc:
            raise MediaRefused(f"damaged {kind}: {exc}") from None
    return Decoded(kind, w, h)


def _flush_c_streams() -> None:
    import ctypes

    sys.stdout.flush()
    sys.stderr.flush()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)  # C stdio buffers (std::cout is synced with them)


@contextlib.contextmanager
def _c_output() -> Iterator[list[str]]:
    """Catch what a C library writes on file descriptors 1 and 2 while the block runs (OpenEXR prints its
    complaints there, stdout included, which would break ``--json``): the lines land in the list it
    yields, not on the user's terminal."""
    lines: list[str] = []
    said = io.StringIO()  # what the binding prints through Python's sys.stdout / sys.stderr
    with tempfile.TemporaryFile() as sink:
        _flush_c_streams()
        saved = [os.dup(1), os.dup(2)]
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
                yield lines
        finally:
            _flush_c_streams()
            for fd, old in zip((1, 2), saved):
                os.dup2(old, fd)
                os.close(old)
            sink.seek(0)
            text = said.getvalue() + sink.read(8192).decode(errors="replace")
            lines.extend(ln.strip() for ln in text.splitlines() if ln.strip())


def _read_exr(path: Path, max_pixels: int) -> tuple[int, int, dict[str, NDArray[np.float32]]]:
    import OpenEXR

    with OpenEXR.File(str(path), header_only=True) as f:
        sizes = [_window(p.header["dataWindow"]) for p in f.parts]
    for pw, ph in sizes or [(0, 0)]:
        over = _over_limit(pw, ph, max_pixels)
        if over:
            raise MediaRefused(over)
    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    return sizes[0][0], sizes[0][1], channels


def _decode_exr(path: Path, max_pixels: int) -> Decoded:
    failure: Optional[str] = None
    with _c_output() as said:
        try:
            w, h, channels = _read_exr(path, max_pixels)
        except MediaRefused:
            raise
        except Exception as exc:  # noqa: BLE001 - the binding raises RuntimeError / ValueError / KeyError
            failure = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if failure is not None:  # the library's own line says more ("corrupt leader ...") than the binding's
        told = [ln.split(": ", 1)[-1] for ln in said if "EXR_ERR" in ln]
        raise MediaRefused(f"damaged OpenEXR: {told[-1] if told else failure}")
    if not channels:
        raise MediaRefused("damaged OpenEXR: no channels")
    colour = [channels[c] for c in ("R", "G", "B", "Y") if c in channels] or list(channels.values())
    return _stats("exr", w, h, colour)


def _window(box: tuple[NDArray[np.int32], NDArray[np.int32]]) -> tuple[int, int]:
    lo, hi = box
    return int(hi[0]) - int(lo[0]) + 1, int(hi[1]) - int(lo[1]) + 1


def _stats(kind: str, width: int, height: int, planes: list[NDArray[np.float32]]) -> Decoded:
    if not planes:
        return Decoded(kind, width, height)
    data = np.stack([np.asarray(p, dtype=np.float32) for p in planes])
    finite = np.isfinite(data)
    bad = int(data.size - int(finite.sum()))
    good = data[finite]
    return Decoded(kind, width, height, float(good.mean()) if good.size else 0.0,
                   float(good.max()) if good.size else 0.0, bad)


# ----------------------------------------------------------------------------- Radiance HDR

_RESOLUTION = ("-Y", "+Y", "-X", "+X")
_RGBE_SCALE = np.array([0.0] + [2.0 ** (e - 136) for e in range(1, 256)], dtype=np.float32)


def _radiance_header(data: bytes) -> tuple[int, int, int]:
    """(width, height, offset of the first scanline) of a Radiance file, or MediaRefused."""
    end = data.find(b"\n\n")
    if end < 0:
        raise MediaRefused("damaged Radiance HDR: the header never ends (no blank line)")
    lines = data[:end].decode("latin-1").splitlines()
    formats = [ln.split("=", 1)[1].strip() for ln in lines if ln.startswith("FORMAT=")]
    if formats and formats[-1] not in ("32-bit_rle_rgbe", "32-bit_rle_xyze"):
        raise MediaRefused(f"Radiance HDR of an unknown pixel format {formats[-1]!r}")
    nl = data.find(b"\n", end + 2)
    res = data[end + 2:nl if nl >= 0 else len(data)].decode("latin-1").split()
    if nl < 0 or len(res) != 4 or res[0] not in _RESOLUTION or res[2] not in _RESOLUTION \
            or not res[1].isdigit() or not res[3].isdigit():
        raise MediaRefused(f"damaged Radiance HDR: no resolution line after the header ({' '.join(res)[:40]!r})")
    first, second = int(res[1]), int(res[3])
    height, width = (first, second) if res[0][1] == "Y" else (second, first)
    return width, height, nl + 1


def _rle_scanline(data: bytes, pos: int, width: int) -> tuple[NDArray[np.uint8], int]:
    """One new-style run-length-encoded scanline (four channels, each its own runs) from ``pos``."""
    out = np.empty((4, width), dtype=np.uint8)
    n = len(data)
    for c in range(4):
        x = 0
        row = out[c]
        while x < width:
            if pos >= n:
                raise MediaRefused("truncated Radiance HDR: the file ends inside a scanline")
            count = data[pos]
            if count > 128:
                count -= 128
                if pos + 1 >= n:
                    raise MediaRefused("truncated Radiance HDR: the file ends inside a scanline")
                if x + count > width:
                    raise MediaRefused("damaged Radiance HDR: a run overruns its scanline")
                row[x:x + count] = data[pos + 1]
                pos += 2
            else:
                if pos + 1 + count > n:
                    raise MediaRefused("truncated Radiance HDR: the file ends inside a scanline")
                if count == 0 or x + count > width:
                    raise MediaRefused("damaged Radiance HDR: a run overruns its scanline")
                row[x:x + count] = np.frombuffer(data, np.uint8, count, pos + 1)
                pos += 1 + count
            x += count
    return out.T, pos


def _flat_scanline(data: bytes, pos: int, width: int, prev: Optional[NDArray[np.uint8]]) -> tuple[NDArray[np.uint8], int]:
    """One flat or old-style run-length scanline (RGBE quadruples; (1, 1, 1, n) repeats the last)."""
    if pos + 4 * width <= len(data):  # flat, the common case: one slice, no repeat markers in it
        quads = np.frombuffer(data, np.uint8, 4 * width, pos).reshape(width, 4)
        if not ((quads[:, 0] == 1) & (quads[:, 1] == 1) & (quads[:, 2] == 1)).any():
            return quads, pos + 4 * width
    out = np.empty((width, 4), dtype=np.uint8)
    x, shift = 0, 0
    last = prev[-1] if prev is not None else None
    while x < width:
        if pos + 4 > len(data):
            raise MediaRefused("truncated Radiance HDR: the file ends inside a scanline")
        quad = np.frombuffer(data, np.uint8, 4, pos)
        pos += 4
        if quad[0] == 1 and quad[1] == 1 and quad[2] == 1:
            count = int(quad[3]) << shift
            if last is None or x + count > width:
                raise MediaRefused("damaged Radiance HDR: a repeat run with nothing to repeat or past its scanline")
            out[x:x + count] = last
            x += count
            shift += 8
            continue
        out[x] = last = quad
        x += 1
        shift = 0
    return out, pos


def read_radiance(path: Path, max_pixels: int) -> NDArray[np.float32]:
    """A Radiance ``.hdr`` file as an (H, W, 3) float32 array, decoded whole, or MediaRefused."""
    data = Path(path).read_bytes()
    if not data.startswith(RADIANCE_MAGICS):
        raise MediaRefused("not a Radiance HDR file (no '#?RADIANCE' magic)")
    width, height, pos = _radiance_header(data)
    over = _over_limit(width, height, max_pixels)
    if over:
        raise MediaRefused(over)
    rgbe = np.empty((height, width, 4), dtype=np.uint8)
    prev: Optional[NDArray[np.uint8]] = None
    for y in range(height):
        head = data[pos:pos + 4]
        if 8 <= width < 0x8000 and len(head) == 4 and head[0] == 2 and head[1] == 2 and not head[2] & 0x80:
            if (head[2] << 8 | head[3]) != width:
                raise MediaRefused(f"damaged Radiance HDR: scanline {y} says width {head[2] << 8 | head[3]}, "
                                   f"the header {width}")
            prev, pos = _rle_scanline(data, pos + 4, width)
        else:
            prev, pos = _flat_scanline(data, pos, width, prev)
        rgbe[y] = prev
    scale: NDArray[np.float32] = _RGBE_SCALE[rgbe[..., 3]]  # mantissa x 2^(exponent - 136); exponent 0 is black
    rgb: NDArray[np.float32] = rgbe[..., :3].astype(np.float32) * scale[..., None]
    return rgb


def _decode_hdr(path: Path, max_pixels: int) -> Decoded:
    rgb = read_radiance(path, max_pixels)
    return _stats("hdr", rgb.shape[1], rgb.shape[0], [rgb[..., i] for i in range(3)])


# ----------------------------------------------------------------------------- the checks


def decode(path: Path | str, max_pixels: int) -> Decoded:
    """Decode ``path`` whole (by its magic bytes: OpenEXR, Radiance HDR, else Pillow), or MediaRefused."""
    path = Path(path)
    try:
        if path.stat().st_size == 0:
            raise MediaRefused("empty file (0 bytes)")
        head = _magic(path)
    except OSError as exc:
        raise MediaRefused(f"unreadable file: {exc.strerror or exc}") from None
    if head[:4] == EXR_MAGIC:
        return _decode_exr(path, max_pixels)
    if head.startswith(RADIANCE_MAGICS):
        return _decode_hdr(path, max_pixels)
    return _decode_pil(path, max_pixels)


def check_texture(path: Path | str, max_pixels: int) -> Optional[str]:
    """Why the image at ``path`` cannot be used as a texture or floor map (truncated, lying about its size,
    over ``max_pixels``, not an image), or None when it decodes whole."""
    try:
        decode(path, max_pixels)
    except MediaRefused as exc:
        return str(exc)
    return None


def check_environment(path: Path | str, max_pixels: int) -> Optional[str]:
    """Why the HDR / EXR at ``path`` cannot light a scene, or None: it must decode whole, hold no NaN or
    infinite value, and not be black everywhere."""
    try:
        found = decode(path, max_pixels)
    except MediaRefused as exc:
        return str(exc)
    if found.kind not in ("exr", "hdr"):
        return f"not an HDR or OpenEXR map (a {found.kind} image)"
    if found.non_finite:
        return (f"{found.non_finite:,} of its {found.width * found.height * 3:,} samples are NaN or infinite "
                "(Cycles renders them black or as speckles)")
    if found.peak <= 0.0:
        return "every pixel is black: it would light nothing"
    return None


class DecodedFiles:
    """The files a catalog already decoded whole, so that a re-ingest does not decode them again.

    Decoding costs about 60 times the hashing of the same bytes (9.2 vs 0.15 CPU-s on 102 MB of public
    textures), and ingest prepares unchanged objects too. A file is known by its real path, size,
    modification time and inode, and by the pixel limit it was checked under; only files that decoded are
    remembered, so a damaged one is checked again on every run (and fails early). ``path`` is a JSON file
    in the catalog's data folder (None: remember for this process only)."""

    def __init__(self, path: Optional[Path]) -> None:
        self.path = path
        self._known: set[str] = set()
        self._added = False
        if path is not None:
            try:
                import json

                self._known = set(json.loads(path.read_text("utf-8")))
            except (OSError, ValueError, TypeError):
                self._known = set()

    @staticmethod
    def _key(file: Path | str, max_pixels: int) -> Optional[str]:
        try:
            st = os.stat(file)
        except OSError:
            return None
        return f"{os.path.realpath(file)}|{st.st_size}|{st.st_mtime_ns}|{st.st_ino}|{max_pixels}"

    def check(self, file: Path | str, max_pixels: int) -> Optional[str]:
        """:func:`check_texture`, skipped for a file this catalog already decoded whole unchanged."""
        key = self._key(file, max_pixels)
        if key is not None and key in self._known:
            return None
        reason = check_texture(file, max_pixels)
        if reason is None and key is not None:
            self._known.add(key)
            self._added = True
        return reason

    def save(self) -> None:
        """Write what was learnt (atomically); nothing when nothing new was decoded."""
        if self.path is None or not self._added:
            return
        import json

        from mixcount.atomic import write_text_atomic

        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path, json.dumps(sorted(self._known)))
        self._added = False


def texture_warnings(files: dict[str, Path], max_pixels: int, decoded: Optional[DecodedFiles] = None) -> list[str]:
    """One warning per image among a model's resource files (reference name -> file) that does not
    decode whole: what ingest flags the object with (its texture would render magenta or not at all).
    ``decoded``: files this catalog already decoded whole (:class:`DecodedFiles`) are not decoded again."""
    out = []
    for ref, file in files.items():
        if Path(file).suffix.lower() not in IMAGE_SUFFIXES:
            continue
        reason = decoded.check(file, max_pixels) if decoded is not None else check_texture(file, max_pixels)
        if reason:
            out.append(f"texture {ref} does not decode: {reason}")
    return out


# ----------------------------------------------------------------------------- renders


def magenta_share(rgb: NDArray[np.uint8], mask: Optional[NDArray[np.bool_]] = None) -> float:
    """The share of pixels (within ``mask`` when given) in Blender's missing-image magenta: red and blue
    within 15 % of each other, above 24 of 255, and green under 10 % of them."""
    px = rgb.reshape(-1, rgb.shape[-1])[:, :3].astype(np.float32)
    if mask is not None:
        px = px[mask.reshape(-1)]
    if not len(px):
        return 0.0
    r, g, b = px[:, 0], px[:, 1], px[:, 2]
    hi = np.maximum(r, b)
    pink = (np.minimum(r, b) > 24) & (np.abs(r - b) <= 0.15 * hi) & (g <= 0.1 * hi)
    return float(pink.mean())


def render_fault(rgb_path: Path | str, mask_path: Optional[Path | str] = None) -> Optional[str]:
    """Why a rendered RGB image is no render of its inputs, or None: black (mean under
    :data:`BLACK_MEAN` of 255: an environment or lights that gave nothing), or Blender's missing-image
    magenta over :data:`MAGENTA_SHARE_SCENE` of the image (a floor or world it could not read) or, with
    ``mask_path`` (a canonical render's object mask), over :data:`MAGENTA_SHARE_OBJECT` of the object."""
    from PIL import Image

    with Image.open(rgb_path) as im:
        rgb = np.asarray(im.convert("RGB"))
    mean = float(rgb.mean())
    if mean < BLACK_MEAN:
        return (f"the render is black (mean {mean:.2f} of 255): no light reached the camera (an environment "
                "map damaged since it was ingested, or lights at zero)")
    mask = None
    if mask_path is not None and Path(mask_path).is_file():
        with Image.open(mask_path) as im:
            mask = np.asarray(im.convert("L")) > 127
    share = magenta_share(rgb, mask)
    limit = MAGENTA_SHARE_OBJECT if mask is not None else MAGENTA_SHARE_SCENE
    if share > limit:
        where = "of the object" if mask is not None else "of the image"
        return (f"the render is Blender's missing-image magenta over {share:.0%} {where}: a texture, floor "
                "or environment file it could not read")
    return None
