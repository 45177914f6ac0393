"""Decode before use (issue 68 item 3): mixcount.catalog.media_check on real files and on damaged copies of
them. The real inputs: bpy's bundled studio-light EXRs, the Radiance HDR in bpy's USD resources,
matplotlib's sample photograph (JPEG) and logos (PNG). The damage is made here: truncation, a header that
lies about the size, a header declaring 40000 x 40000 pixels (crafted, nothing allocated), NaN pixels, a
flipped byte, an empty file."""

from __future__ import annotations

import struct
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.catalog import media_check as M
from mixcount.scene.bundled_environments import bpy_package_dir, bundled_hdri_dir

LIMIT = 67108864  # configs/default.toml [ingest] max_image_pixels
MPL_DATA = Path(__import__("matplotlib").get_data_path()) / "sample_data"


def _bundled_exr(name: str = "night") -> Path:
    return bundled_hdri_dir() / f"{name}.exr"


def _stinson() -> Path:
    path = bpy_package_dir() / "lib" / "usd" / "hdx" / "resources" / "textures" / "StinsonBeach.hdr"
    # bpy is pinned in pyproject.toml (5.0.1) and ships this file: a missing one is a failure, not a skip
    assert path.is_file(), f"no Radiance HDR in this bpy install ({path}): the pinned bpy changed?"
    return path


def _cut(src: Path, dst: Path, keep: float) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * keep)])
    return dst


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _lying_png(src: Path, dst: Path, w: int, h: int) -> Path:
    """``src`` (a real PNG) with its IHDR saying ``w`` x ``h`` (checksum fixed, so only the size lies)."""
    data = bytearray(src.read_bytes())
    body = b"IHDR" + struct.pack(">II", w, h) + bytes(data[24:29])
    data[16:24] = struct.pack(">II", w, h)
    data[29:33] = struct.pack(">I", zlib.crc32(body))
    dst.write_bytes(bytes(data))
    return dst


def test_real_files_decode_whole() -> None:
    for name in ("night", "studio", "forest"):
        found = M.decode(_bundled_exr(name), LIMIT)
        assert (found.kind, found.width, found.height) == ("exr", 1024, 512)
        assert found.non_finite == 0 and found.peak > 0.5 and 0.0 < found.mean < found.peak
        assert M.check_environment(_bundled_exr(name), LIMIT) is None
    hdr = M.decode(_stinson(), LIMIT)
    assert (hdr.kind, hdr.width, hdr.height) == ("hdr", 1024, 512) and hdr.non_finite == 0 and hdr.mean > 0.05
    assert M.check_environment(_stinson(), LIMIT) is None
    for name in ("grace_hopper.jpg", "Minduka_Present_Blue_Pack.png", "logo2.png"):
        assert M.check_texture(MPL_DATA / name, LIMIT) is None, name
    assert M.decode(MPL_DATA / "grace_hopper.jpg", LIMIT).kind == "jpeg"


def test_radiance_reader_gives_the_rgbe_values(tmp_path: Path) -> None:
    """Flat RGBE quadruples and new-style run-length scanlines decode to mantissa x 2^(exponent - 136)."""
    flat = tmp_path / "flat.hdr"
    flat.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 3\n" + bytes([128, 64, 200, 129]) * 6)
    rgb = M.read_radiance(flat, LIMIT)
    assert rgb.shape == (2, 3, 3) and np.allclose(rgb[0, 0], [1.0, 0.5, 1.5625])
    w = 16  # one RLE scanline: each channel a run of 16 equal bytes
    rle = b"".join(bytes([2, 2, 0, w]) + b"".join(bytes([128 + w, v]) for v in (128, 32, 255, 130)) for _ in range(2))
    (tmp_path / "rle.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 16\n" + rle)
    rgb = M.read_radiance(tmp_path / "rle.hdr", LIMIT)
    assert rgb.shape == (2, 16, 3) and np.allclose(rgb[1, 15], [2.0, 0.5, 255 / 64])


@pytest.mark.parametrize("keep", [0.002, 0.3, 0.9, 0.9999])
def test_a_truncated_exr_environment_is_refused_with_the_librarys_reason(tmp_path: Path, keep: float,
                                                                        capfd: pytest.CaptureFixture[str]) -> None:
    cut = _cut(_bundled_exr(), tmp_path / "night.exr", keep)
    assert cut.read_bytes()[:4] == M.EXR_MAGIC  # the magic bytes alone (the old check) say nothing
    reason = M.check_environment(cut, LIMIT)
    assert reason is not None and reason.startswith("damaged OpenEXR: "), reason
    if keep > 0.01:
        assert "EXR_ERR_BAD_CHUNK_LEADER" in reason  # the library's own line, caught from its C output
    out, err = capfd.readouterr()
    assert "Exception raised" not in out + err and "EXR_ERR" not in out + err  # nothing leaks to stdout (--json)


@pytest.mark.parametrize("keep", [0.01, 0.5, 0.999])
def test_a_truncated_hdr_is_refused(tmp_path: Path, keep: float) -> None:
    reason = M.check_environment(_cut(_stinson(), tmp_path / "beach.hdr", keep), LIMIT)
    assert reason is not None and "Radiance HDR" in reason, reason
    if keep > 0.1:
        assert reason.startswith("truncated Radiance HDR: the file ends inside a scanline")


@pytest.mark.parametrize("name", ["grace_hopper.jpg", "Minduka_Present_Blue_Pack.png", "logo2.png"])
def test_truncated_real_textures_are_refused(tmp_path: Path, name: str) -> None:
    for keep in (0.5, 0.95):
        reason = M.check_texture(_cut(MPL_DATA / name, tmp_path / name, keep), LIMIT)
        assert reason is not None and "truncated" in reason, (keep, reason)
    with Image.open(tmp_path / name) as im:  # Pillow opens it without complaint: only decoding tells
        assert im.size == Image.open(MPL_DATA / name).size


def test_a_png_whose_header_lies_about_its_size(tmp_path: Path) -> None:
    real = MPL_DATA / "logo2.png"
    w, h = Image.open(real).size
    lie = _lying_png(real, tmp_path / "lie.png", w * 4, h * 4)
    assert Image.open(lie).size == (w * 4, h * 4)
    reason = M.check_texture(lie, LIMIT)
    assert reason is not None and reason.startswith("damaged png: "), reason


def test_a_declared_40000_square_png_is_refused_without_decoding(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", 40000, 40000, 8, 2, 0, 0, 0))
                     + _chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + _chunk(b"IEND", b""))
    t = time.perf_counter()
    reason = M.check_texture(bomb, LIMIT)
    assert time.perf_counter() - t < 2.0
    assert reason == ("declares 1,600,000,000 pixels, over the limit of 67,108,864 ([ingest] max_image_pixels); "
                      "not decoded (Pillow's decompression-bomb check)")
    # between the limit and twice it Pillow only warns: that warning is a refusal too, and the limit is the config's
    small = _lying_png(MPL_DATA / "logo2.png", tmp_path / "over.png", 300, 300)
    reason = M.check_texture(small, 300 * 300 - 1)
    assert reason is not None and "over the limit of 89,999" in reason
    assert Image.MAX_IMAGE_PIXELS != 300 * 300 - 1  # restored after the check


def test_exr_and_hdr_headers_declaring_40000_square_are_refused_before_decoding(tmp_path: Path) -> None:
    data = bytearray(_bundled_exr().read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at + 8:at + 16] = struct.pack("<2i", 39999, 39999)
    (tmp_path / "bomb.exr").write_bytes(bytes(data))
    (tmp_path / "bomb.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 40000 +X 40000\n" + b"\2\2" * 8)
    for name in ("bomb.exr", "bomb.hdr"):
        t = time.perf_counter()
        reason = M.check_environment(tmp_path / name, LIMIT)
        assert time.perf_counter() - t < 2.0
        assert reason == ("declares 40000 x 40000 pixels (1,600,000,000), over the limit of 67,108,864 "
                          "([ingest] max_image_pixels); not decoded"), name


def test_damage_the_issue_does_not_name(tmp_path: Path) -> None:
    """An EXR that decodes but holds NaN, one that is black everywhere, an empty file, a PNG with one byte of
    its pixel data flipped (the chunk checksum tells), a text file named .png."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    nan = np.full((8, 16), 0.5, np.float32)
    nan[2:4, 3:9] = np.nan
    OpenEXR.File(header, {"R": nan, "G": nan, "B": nan}).write(str(tmp_path / "nan.exr"))
    zero = np.zeros((8, 16), np.float32)
    OpenEXR.File(header, {"R": zero, "G": zero, "B": zero}).write(str(tmp_path / "black.exr"))
    assert M.check_texture(tmp_path / "nan.exr", LIMIT) is None  # it decodes ...
    assert M.check_environment(tmp_path / "nan.exr", LIMIT) == (
        "36 of its 384 samples are NaN or infinite (Cycles renders them black or as speckles)")  # ... but lights badly
    assert M.check_environment(tmp_path / "black.exr", LIMIT) == "every pixel is black: it would light nothing"
    (tmp_path / "empty.exr").write_bytes(b"")
    assert M.check_environment(tmp_path / "empty.exr", LIMIT) == "empty file (0 bytes)"
    data = bytearray((MPL_DATA / "logo2.png").read_bytes())
    idat = data.index(b"IDAT")
    data[idat + 200] ^= 0xFF
    (tmp_path / "flipped.png").write_bytes(bytes(data))
    reason = M.check_texture(tmp_path / "flipped.png", LIMIT)
    assert reason is not None and reason.startswith("damaged png: "), reason
    (tmp_path / "text.png").write_text("not an image")
    assert M.check_texture(tmp_path / "text.png", LIMIT) == "not an image Pillow can read (unknown or damaged header)"
    assert M.check_environment(MPL_DATA / "logo2.png", LIMIT) == "not an HDR or OpenEXR map (a png image)"


def test_texture_warnings_name_each_damaged_image_of_a_model(tmp_path: Path) -> None:
    good = MPL_DATA / "logo2.png"
    cut = _cut(MPL_DATA / "grace_hopper.jpg", tmp_path / "hopper.jpg", 0.5)
    mtl = tmp_path / "m.mtl"
    mtl.write_text("newmtl a\n")
    found = M.texture_warnings({"logo2.png": good, "tex/hopper.jpg": cut, "m.mtl": mtl}, LIMIT)
    assert found == ["texture tex/hopper.jpg does not decode: damaged jpeg: image file is truncated "
                     f"({found[0].rsplit('(', 1)[1]}"]


def test_render_fault_black_and_magenta(tmp_path: Path) -> None:
    photo = MPL_DATA / "grace_hopper.jpg"
    assert M.render_fault(photo) is None
    black = np.zeros((32, 32, 3), np.uint8)
    black[5, 5] = 30  # one lit pixel does not make a render
    Image.fromarray(black).save(tmp_path / "black.png")
    assert M.render_fault(tmp_path / "black.png").startswith("the render is black (mean 0.03 of 255)")
    shaded = np.asarray(Image.open(photo).convert("L").resize((64, 48)), np.float32)[..., None] / 255.0
    pink = ((0.3 + 0.7 * shaded) * np.array([255, 0, 255])).astype(np.uint8)  # a lit missing image
    scene = np.asarray(Image.open(photo).convert("RGB").resize((64, 48))).copy()
    scene[24:] = pink[24:]  # the lower half (a floor) magenta
    Image.fromarray(scene).save(tmp_path / "floor.png")
    assert "magenta over 50% of the image" in M.render_fault(tmp_path / "floor.png")
    scene[24:40] = np.asarray(Image.open(photo).convert("RGB").resize((64, 48)))[24:40]  # a small pink patch: kept
    Image.fromarray(scene).save(tmp_path / "patch.png")
    assert M.render_fault(tmp_path / "patch.png") is None
    # a canonical render: white background, the object pink inside its mask
    canon = np.full((48, 64, 3), 255, np.uint8)
    mask = np.zeros((48, 64), np.uint8)
    mask[10:30, 20:40] = 255
    canon[10:30, 20:40] = pink[10:30, 20:40]
    Image.fromarray(canon).save(tmp_path / "canon.png")
    Image.fromarray(mask).save(tmp_path / "canon_mask.png")
    assert M.render_fault(tmp_path / "canon.png") is None  # 13 % of the image: not enough without the mask
    assert "magenta over 100% of the object" in M.render_fault(tmp_path / "canon.png", tmp_path / "canon_mask.png")
    # a real magenta look (the palette's (200, 40, 190)) is no missing image
    canon[10:30, 20:40] = (shaded[10:30, 20:40] * np.array([200, 40, 190])).astype(np.uint8)
    Image.fromarray(canon).save(tmp_path / "plastic.png")
    assert M.render_fault(tmp_path / "plastic.png", tmp_path / "canon_mask.png") is None


def test_a_reingest_does_not_decode_a_file_again_until_it_changes(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """DecodedFiles: a file decoded whole is remembered (by path, size, mtime, inode and the limit) across
    catalogs opened again; one changed since (cut short here) is decoded again and refused."""
    tex = tmp_path / "hopper.jpg"
    tex.write_bytes((MPL_DATA / "grace_hopper.jpg").read_bytes())
    memo_file = tmp_path / "data" / "decoded.json"
    first = M.DecodedFiles(memo_file)
    assert M.texture_warnings({"hopper.jpg": tex}, LIMIT, first) == []
    first.save()
    assert memo_file.is_file()

    decodes: list[Path] = []
    real_check = M.check_texture
    monkeypatch.setattr(M, "check_texture", lambda f, p: decodes.append(Path(f)) or real_check(f, p))
    again = M.DecodedFiles(memo_file)  # the next ingest: known, not decoded
    assert M.texture_warnings({"hopper.jpg": tex}, LIMIT, again) == [] and decodes == []
    assert M.texture_warnings({"hopper.jpg": tex}, LIMIT // 2, again) == [] and decodes == [tex]  # another limit
    _cut(MPL_DATA / "grace_hopper.jpg", tex, 0.5)  # replaced by a damaged copy: checked and refused
    found = M.texture_warnings({"hopper.jpg": tex}, LIMIT, again)
    assert len(decodes) == 2 and len(found) == 1 and "truncated" in found[0]
