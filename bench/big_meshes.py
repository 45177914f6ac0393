"""Capture-like big meshes for the ingest benches, written straight from numpy (seconds, little memory).

:func:`lumpy_grid` is a scan-like closed-looking blob (a latitude / longitude grid, open at the poles like
a turntable capture, with smooth lumps and a little noise) of about ``faces`` triangles.
:func:`write_ply` writes it as a binary PLY with per-vertex colours (what a photogrammetry or phone scan
exports); :func:`write_textured_glb` as a GLB with UVs and a ``texture_px`` JPEG texture (the DTC layout's
``3d-asset.glb``: over a million faces and 4K textures). Both are seeded and deterministic.
"""

from __future__ import annotations

import io
import json
import math
import struct
from pathlib import Path

import numpy as np


def lumpy_grid(faces: int, seed: int, radius: float = 0.06) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3) in metres, faces int32 (F, 3), uv float32 (V, 2)) of about ``faces`` triangles."""
    rng = np.random.default_rng(seed)
    nv = max(4, int(round(math.sqrt(faces / 2.0 / 1.25))))  # latitude rows
    nu = max(4, int(round(faces / 2.0 / (nv - 1))))  # longitude columns (the seam closes the ring)
    lat = np.linspace(0.04 * math.pi, 0.96 * math.pi, nv, dtype=np.float32)
    lon = np.linspace(0.0, 2.0 * math.pi, nu, endpoint=False, dtype=np.float32)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    lumps = np.zeros_like(la)
    for _ in range(6):
        a, b, c, d = rng.uniform(1.0, 5.0), rng.uniform(1.0, 5.0), rng.uniform(0, 6.3), rng.uniform(0.02, 0.07)
        lumps += d * np.sin(a * la + c) * np.cos(b * lo)
    r = radius * (1.0 + lumps + rng.normal(0.0, 0.002, la.shape).astype(np.float32))
    verts = np.stack([r * np.sin(la) * np.cos(lo), r * np.sin(la) * np.sin(lo), 1.3 * r * np.cos(la)], axis=-1)
    verts = verts.reshape(-1, 3).astype(np.float32)
    uv = np.stack([(lo / (2 * math.pi)).ravel(), (la / math.pi).ravel()], axis=-1).astype(np.float32)
    i, j = np.meshgrid(np.arange(nv - 1, dtype=np.int32), np.arange(nu, dtype=np.int32), indexing="ij")
    a = i * nu + j
    b = i * nu + (j + 1) % nu
    c = (i + 1) * nu + j
    d = (i + 1) * nu + (j + 1) % nu
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return verts, tris.astype(np.int32), uv


def write_ply(path: Path, verts: np.ndarray, faces: np.ndarray, seed: int) -> None:
    """Binary little-endian PLY with uchar vertex colours, as scanners write them."""
    rng = np.random.default_rng(seed)
    vdtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vrec = np.empty(len(verts), dtype=vdtype)
    vrec["x"], vrec["y"], vrec["z"] = verts[:, 0], verts[:, 1], verts[:, 2]
    base = rng.integers(60, 200, 3)
    shade = (verts[:, 2] - verts[:, 2].min()) / max(float(np.ptp(verts[:, 2])), 1e-9)
    for k, name in enumerate(("red", "green", "blue")):
        vrec[name] = np.clip(base[k] * (0.6 + 0.4 * shade), 0, 255).astype(np.uint8)
    fdtype = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    frec = np.empty(len(faces), dtype=fdtype)
    frec["n"], frec["i"] = 3, faces
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vrec.tobytes())
        fh.write(frec.tobytes())


def texture_jpeg(px: int, seed: int) -> bytes:
    """A ``px`` x ``px`` JPEG of smooth colour blotches and fine grain (a baked capture atlas)."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    small = rng.integers(40, 220, (16, 16, 3), dtype=np.uint8)
    img = np.asarray(Image.fromarray(small).resize((px, px), Image.Resampling.BICUBIC), dtype=np.int16)
    img = img + rng.integers(-12, 13, (px, px, 1), dtype=np.int16)
    buf = io.BytesIO()
    Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)).save(buf, format="JPEG", quality=90)
    return buf.getvalue()


def write_textured_glb(path: Path, verts: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture_px: int,
                       seed: int) -> None:
    """One-mesh glTF 2.0 binary: positions, UVs, uint32 indices, a base-colour JPEG of ``texture_px``."""
    image = texture_jpeg(texture_px, seed)
    blobs = [np.ascontiguousarray(verts, "<f4").tobytes(), np.ascontiguousarray(uv, "<f4").tobytes(),
             np.ascontiguousarray(faces, "<u4").tobytes(), image]
    views, offset, body = [], 0, bytearray()
    for blob in blobs:
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(blob)})
        body += blob + b"\0" * (-len(blob) % 4)
        offset = len(body)
    lo, hi = verts.min(axis=0).tolist(), verts.max(axis=0).tolist()
    gltf = {
        "asset": {"version": "2.0", "generator": "mixcount bench/big_meshes.py"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0}}],
        "textures": [{"source": 0}], "images": [{"bufferView": 3, "mimeType": "image/jpeg"}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(verts), "type": "VEC3", "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": len(uv), "type": "VEC2"},
            {"bufferView": 2, "componentType": 5125, "count": int(faces.size), "type": "SCALAR"},
        ],
        "bufferViews": views, "buffers": [{"byteLength": len(body)}],
    }
    js = json.dumps(gltf, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(body)
    with open(path, "wb") as fh:
        fh.write(struct.pack("<III", 0x46546C67, 2, total))
        fh.write(struct.pack("<II", len(js), 0x4E4F534A) + js)
        fh.write(struct.pack("<II", len(body), 0x004E4942) + bytes(body))
