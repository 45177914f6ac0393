"""Copies of an object the way another source would publish it, rebuilt from its surface (numpy, scipy, pymeshlab).

The older demo traps copy an object's mesh data (the same vertices turned, scaled or split in four). A
second source's copy of a scan shares none of that: it was remeshed or decimated, its texture re-baked
into another UV layout at another resolution, stored in other units with another up axis and origin,
and cut into other parts. The functions here make such copies from the original's *surface* only:

* :func:`surface_colour` samples the original densely (area-weighted, with the colour its image
  texture or vertex colours give each point), the reference every re-bake reads from;
* :func:`weld` bakes the parts' placements into one mesh and merges coincident vertices (UV seams,
  revolve seams), which remeshing needs;
* :func:`remesh` runs pymeshlab's isotropic explicit remeshing or quadric edge-collapse decimation
  to a target face count;
* :func:`bake` lays the mesh out in a new per-triangle texture atlas (each triangle its own half of a
  grid cell, with a gutter) and fills every texel with the colour of the nearest dense sample of the
  original surface: a re-baked texture at another resolution, whatever the original's UVs were;
* :func:`split` cuts a mesh into pieces along its longest principal axis, each piece its own part
  whose origin is its own centre (stored as the part's node offset).

:func:`scan_like` makes a capture-sized stand-in for a scan (hundreds of thousands of faces, image
texture) for tests and benchmarks.

Everything is deterministic from the seeds it is given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

    from mixcount.demo.geometry import Part


@dataclass
class SurfaceColour:
    """Dense coloured samples of a surface and a KD-tree over them: the colour nearest a 3-D point."""

    points: np.ndarray
    colours: np.ndarray  # (n, 3) uint8
    tree: "cKDTree"

    def colour_at(self, points: np.ndarray) -> np.ndarray:
        _, idx = self.tree.query(np.asarray(points, dtype=np.float64), k=1)
        return self.colours[idx]


def _bilinear(image: Image.Image, uv: np.ndarray) -> np.ndarray:
    """Colours (0..255 float) of an RGB image at glTF-style UVs (v up, wrapping), bilinear."""
    img = np.asarray(image.convert("RGB"), dtype=np.float64)
    h, w = img.shape[:2]
    x = np.mod(uv[:, 0], 1.0) * (w - 1)
    y = (1.0 - np.mod(uv[:, 1], 1.0)) * (h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def _triangle_areas(tri: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def surface_colour(parts: list[Part], *, seed: int, n: int = 200_000) -> SurfaceColour:
    """``n`` area-weighted samples of the parts (offsets applied) with their base colour."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    tris = [(p.vertices + np.asarray(p.offset))[p.faces] for p in parts]
    areas = np.concatenate([_triangle_areas(t) for t in tris])
    which = rng.choice(len(areas), size=n, p=areas / areas.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.c_[1 - s, s * (1 - r2), s * r2]
    offsets = np.cumsum([0] + [len(p.faces) for p in parts])
    points = np.empty((n, 3))
    colours = np.empty((n, 3))
    for k, p in enumerate(parts):
        sel = np.nonzero((which >= offsets[k]) & (which < offsets[k + 1]))[0]
        if not len(sel):
            continue
        local = which[sel] - offsets[k]
        points[sel] = np.einsum("nk,nkd->nd", bary[sel], tris[k][local])
        corners = p.faces[local]
        if p.image is not None:
            uv = np.einsum("nk,nkd->nd", bary[sel], np.asarray(p.uv, dtype=np.float64)[corners])
            colours[sel] = _bilinear(p.image, uv)
        elif p.colors is not None:
            colours[sel] = np.einsum("nk,nkc->nc", bary[sel], p.colors[:, :3].astype(np.float64)[corners])
        else:
            colours[sel] = 178.0
    return SurfaceColour(points, np.clip(colours.round(), 0, 255).astype(np.uint8),
                         cKDTree(points, balanced_tree=False, compact_nodes=False))


def weld(parts: list[Part], *, tolerance: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """All parts as one mesh (offsets baked in), coincident vertices merged, unused ones dropped."""
    vertices = np.vstack([p.vertices + np.asarray(p.offset) for p in parts])
    faces = np.vstack([p.faces + o for p, o in zip(parts, np.cumsum([0] + [len(p.vertices) for p in parts]))])
    keys = np.round(vertices / tolerance).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return vertices[first], faces


def remesh(vertices: np.ndarray, faces: np.ndarray, *, method: str, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """pymeshlab isotropic explicit remeshing (``method="isotropic"``: the target edge length of
    equilateral triangles covering the area in ``target_faces``) or quadric edge-collapse decimation
    (``"decimate"``) of a mesh. Returns the new vertices and faces."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(vertices, dtype=np.float64),
                               face_matrix=np.asarray(faces, dtype=np.int32)))
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_null_faces()
    if method == "isotropic":
        area = float(_triangle_areas(np.asarray(vertices)[np.asarray(faces)]).sum())
        edge = math.sqrt(area / (target_faces * math.sqrt(3) / 4))
        ms.meshing_isotropic_explicit_remeshing(iterations=6, targetlen=pymeshlab.PureValue(edge))
    elif method == "decimate":
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces), preservenormal=True,
                                                    preservetopology=True, planarquadric=True, autoclean=True)
    else:
        raise ValueError(f"unknown remesh method {method!r} (isotropic or decimate)")
    mesh = ms.current_mesh()
    return np.asarray(mesh.vertex_matrix(), dtype=np.float64), np.asarray(mesh.face_matrix(), dtype=np.int64)


def atlas_layout(n_faces: int, size: int, gutter_px: float = 1.0) -> np.ndarray:
    """Per-wedge UVs (n_faces, 3, 2) of a per-triangle atlas: a grid of square cells, two triangles per
    cell (lower-left and upper-right halves), each inset by ``gutter_px`` so no texel is shared."""
    cols = max(1, math.ceil(math.sqrt(math.ceil(n_faces / 2))))
    cell = 1.0 / cols
    g = gutter_px / size / cell  # gutter in cell units
    k = np.arange(n_faces)
    pair, upper = k // 2, k % 2 == 1
    cx, cy = (pair % cols).astype(np.float64), (pair // cols).astype(np.float64)
    lower_tri = np.array([[g, g], [1 - 2 * g, g], [g, 1 - 2 * g]])
    upper_tri = np.array([[1 - g, 1 - g], [2 * g, 1 - g], [1 - g, 2 * g]])
    local = np.where(upper[:, None, None], upper_tri[None], lower_tri[None])
    return (local + np.stack([cx, cy], axis=1)[:, None, :]) * cell


def bake(vertices: np.ndarray, faces: np.ndarray, colour: SurfaceColour, *, size: int = 512, gain: float = 1.0,
         roughness: float = 0.5, metallic: float = 0.0) -> Part:
    """The mesh as a triangle soup with a new per-triangle atlas (:func:`atlas_layout`) in a texture of
    about ``size`` texels a side (at least 6 texels per cell, so a fine mesh gets a larger texture) whose
    every texel holds the colour of the original surface nearest to the point it maps to (barycentrics
    clamped into the texel's own triangle), times ``gain`` (a re-bake under other lighting)."""
    from mixcount.demo.geometry import Part

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cols = max(1, math.ceil(math.sqrt(math.ceil(len(f) / 2))))
    size = cols * max(6, size // cols)
    uv = atlas_layout(len(f), size)
    # texel centres -> (cell, side, barycentrics of that side's inset triangle)
    px = (np.arange(size) + 0.5) / size
    xs, ys = np.meshgrid(px, 1.0 - px)  # image row 0 is v = 1
    u, w = xs.ravel() * cols, ys.ravel() * cols
    cx, cy = np.floor(u).clip(0, cols - 1), np.floor(w).clip(0, cols - 1)
    s, t = u - cx, w - cy
    face = (cy * cols + cx).astype(np.int64) * 2 + (s + t > 1.0)
    valid = face < len(f)
    face = np.where(valid, face, 0)
    corners = uv[face] * cols - np.stack([cx, cy], axis=1)[:, None, :]  # the triangle in cell units
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    p = np.stack([s, t], axis=1)
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    bary = np.clip(np.stack([1 - l1 - l2, l1, l2], axis=1), 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    points = np.einsum("nk,nkd->nd", bary, v[f[face]])
    texels = np.clip(colour.colour_at(points) * gain, 0, 255).round().astype(np.uint8)
    texels[~valid] = texels[valid].mean(axis=0).astype(np.uint8) if valid.any() else 128
    image = Image.fromarray(texels.reshape(size, size, 3), "RGB")
    soup = v[f].reshape(-1, 3)
    return Part(soup, np.arange(len(soup)).reshape(-1, 3), uv.reshape(-1, 2), image=image,
                roughness=roughness, metallic=metallic)


def split(part: Part, pieces: int) -> list[Part]:
    """``part`` cut into ``pieces`` parts by face centroid along its longest principal axis (equal face
    counts); each piece keeps its vertices' UVs / colours and stores its centre as its offset."""
    from mixcount.demo.geometry import Part

    v = np.asarray(part.vertices, dtype=np.float64) + np.asarray(part.offset)
    centroids = v[part.faces].mean(axis=1)
    centred = centroids - centroids.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    order = np.argsort(centred @ axis, kind="stable")
    out = []
    for chunk in np.array_split(order, pieces):
        sub = part.faces[np.sort(chunk)]
        used, local = np.unique(sub, return_inverse=True)
        centre = v[used].mean(axis=0)
        out.append(Part(v[used] - centre, local.reshape(-1, 3), np.asarray(part.uv)[used], image=part.image,
                        colors=None if part.colors is None else part.colors[used], roughness=part.roughness,
                        metallic=part.metallic, offset=tuple(float(x) for x in centre)))  # type: ignore[arg-type]
    return out


def scan_like(faces: int, rng: np.random.Generator) -> Part:
    """A capture-sized scan stand-in: an icosphere with enough subdivisions for about ``faces`` faces,
    pushed into a lumpy potato shape (about 16 x 10 x 8 cm), with a blocky random texture through
    spherical UVs."""
    import trimesh

    from mixcount.demo.geometry import Part

    level = max(1, int(round(np.log(faces / 20) / np.log(4))))
    mesh = trimesh.creation.icosphere(subdivisions=level, radius=0.05)
    v = np.asarray(mesh.vertices)
    d = v / np.linalg.norm(v, axis=1, keepdims=True)
    bumps = sum(a * np.sin(k * d @ rng.normal(size=3)) for a, k in ((0.12, 3.0), (0.05, 7.0), (0.02, 15.0)))
    v = v * (1.0 + bumps)[:, None] * np.array([1.6, 1.0, 0.8])
    uv = np.c_[0.5 + np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 0.5 + np.arcsin(d[:, 2].clip(-1, 1)) / np.pi]
    img = Image.fromarray(np.uint8(rng.integers(0, 255, (64, 64, 3)))).resize((256, 256), Image.Resampling.NEAREST)
    return Part(v, np.asarray(mesh.faces), uv, image=img, roughness=0.6)


def republish(parts: list[Part], *, method: str | None, target_faces: int, texture_px: int, rotation: np.ndarray,
              scale: float, seed: int, gain: float = 1.0, pieces: int = 1) -> list[Part]:
    """``parts`` as another source would publish them: remeshed (``method`` isotropic / decimate, or
    None to keep the surface's triangles), re-baked into a new atlas of about ``texture_px`` texels a
    side (times ``gain``), turned by ``rotation`` (3x3) about the origin, times ``scale`` (units), and
    cut into ``pieces`` parts with their own origins."""
    from mixcount.demo.geometry import Part

    colour = surface_colour(parts, seed=seed)
    vertices, faces = weld(parts)
    if method is not None:
        vertices, faces = remesh(vertices, faces, method=method, target_faces=target_faces)
    first = parts[0]
    baked = bake(vertices, faces, colour, size=texture_px, gain=gain, roughness=first.roughness, metallic=first.metallic)
    baked = Part(baked.vertices @ np.asarray(rotation).T * scale, baked.faces, baked.uv, image=baked.image,
                 roughness=baked.roughness, metallic=baked.metallic)
    return split(baked, pieces) if pieces > 1 else [baked]
