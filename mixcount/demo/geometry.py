"""Demo-library geometry: mesh parts with UVs (Z-up metres) and the shapes the object builders use
(revolves, boxes, extrusions, tori, outlines), plus the transforms the curation traps apply to them
(turn and rescale with offsets baked in, re-tessellation, recolouring)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PIL import Image

# Z-up (Blender, USD here) -> glTF Y-up: (x, y, z) -> (x, z, -y). Ingest undoes it.
ZUP_TO_YUP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])


@dataclass
class Part:
    """One mesh part: Z-up metres, per-vertex UVs, and its appearance (image or vertex colours)."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    image: Image.Image | None = None
    colors: np.ndarray | None = None  # (n, 4) uint8 when vertex-coloured
    roughness: float = 0.5
    metallic: float = 0.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # placement, written as the node transform


def revolve(
    profile: list[tuple[float, float]], sections: int = 32, squircle: tuple[float, float, float] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface of revolution about Z of a (radius, z) polyline, with a UV seam; pole rings (r = 0)
    get triangles only, so there are no zero-area faces. The polyline goes from the bottom outwards.
    ``squircle=(ax, ay, n)`` sweeps it around a superellipse instead of a circle (n = 2: ellipse; n = 8:
    rounded rectangle), which makes closed trays and boxy bottles."""
    prof = np.asarray(profile, dtype=np.float64)
    m = len(prof)
    seg = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(prof, axis=0), axis=1))]
    v_coord = seg / seg[-1]
    theta = np.linspace(0.0, 2 * np.pi, sections + 1)
    cos, sin = np.cos(theta), np.sin(theta)
    cos[-1], sin[-1] = 1.0, 0.0  # exact seam, so the duplicated column merges on ingest
    if squircle is not None:
        ax, ay, n = squircle
        cos = ax * np.sign(cos) * np.abs(cos) ** (2.0 / n)
        sin = ay * np.sign(sin) * np.abs(sin) ** (2.0 / n)
    verts = np.empty(((sections + 1) * m, 3))
    uvs = np.empty(((sections + 1) * m, 2))
    for j in range(sections + 1):
        block = slice(j * m, (j + 1) * m)
        verts[block, 0] = prof[:, 0] * cos[j]
        verts[block, 1] = prof[:, 0] * sin[j]
        verts[block, 2] = prof[:, 1]
        uvs[block, 0] = j / sections
        uvs[block, 1] = v_coord
    faces = []
    for j in range(sections):
        for i in range(m - 1):
            a, b, c, d = j * m + i, (j + 1) * m + i, (j + 1) * m + i + 1, j * m + i + 1
            if prof[i, 0] > 0:
                faces.append((a, b, c))
            if prof[i + 1, 0] > 0:
                faces.append((a, c, d))
    return verts, np.asarray(faces, dtype=np.int64), uvs


def box(extents: tuple[float, float, float], atlas: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis-aligned box centred on the origin, 4 vertices per face; with ``atlas=(cols, rows)`` each of
    the 6 faces maps to its own cell of the texture (dice pips, letter blocks), else to the whole image."""
    hx, hy, hz = (e / 2 for e in extents)
    # (normal axis, sign, the two in-plane axes u, v) with u x v = normal so faces wind outwards
    spec = [(2, 1, 0, 1), (2, -1, 1, 0), (0, 1, 1, 2), (0, -1, 2, 1), (1, 1, 2, 0), (1, -1, 0, 2)]
    half = np.array([hx, hy, hz])
    verts, uvs, faces = [], [], []
    for k, (n, sgn, ua, va) in enumerate(spec):
        base = len(verts)
        for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[n] = sgn * half[n]
            p[ua] = du * half[ua]
            p[va] = dv * half[va]
            verts.append(p)
            u, v = (du + 1) / 2, (dv + 1) / 2
            if atlas:
                cols, rows = atlas
                u, v = ((k % cols) + 0.06 + 0.88 * u) / cols, ((k // cols) + 0.06 + 0.88 * v) / rows
            uvs.append((u, v))
        faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.asarray(verts), np.asarray(faces, dtype=np.int64), np.asarray(uvs)


def extrude(outline: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prism of a star-shaped (from its centroid) counter-clockwise 2-D outline, z in [0, height]."""
    pts = np.asarray(outline, dtype=np.float64)
    n = len(pts)
    centre = pts.mean(axis=0)
    span = np.ptp(pts, axis=0).max()
    verts, uvs, faces = [], [], []
    for z, up in ((0.0, False), (height, True)):
        base = len(verts)
        verts.append((*centre, z))
        uvs.append((0.5, 0.5))
        for p in pts:
            verts.append((p[0], p[1], z))
            uvs.append((0.5 + (p[0] - centre[0]) / span, 0.5 + (p[1] - centre[1]) / span))
        for i in range(n):
            a, b = base + 1 + i, base + 1 + (i + 1) % n
            faces.append((base, a, b) if up else (base, b, a))
    perim = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(np.vstack([pts, pts[:1]]), axis=0), axis=1))]
    for i in range(n):
        j = (i + 1) % n
        base = len(verts)
        for p, u in ((pts[i], perim[i]), (pts[j], perim[i + 1])):
            verts += [(p[0], p[1], 0.0), (p[0], p[1], height)]
            uvs += [(u / perim[-1], 0.0), (u / perim[-1], 1.0)]
        faces += [(base, base + 2, base + 3), (base, base + 3, base + 1)]
    return np.asarray(verts), np.asarray(faces, dtype=np.int64), np.asarray(uvs)


def torus(major: float, minor: float, sections: int = 32, rings: int = 12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Torus about Z as a revolve of a circle (closed profile duplicated at its ends)."""
    phi = np.linspace(-np.pi / 2, 3 * np.pi / 2, rings + 1)
    profile = [(major + minor * np.cos(p), minor * np.sin(p)) for p in phi]
    return revolve(profile, sections)


def star(n: int, r_out: float, r_in: float) -> np.ndarray:
    ang = np.arange(2 * n) * np.pi / n
    rad = np.where(np.arange(2 * n) % 2 == 0, r_out, r_in)
    return np.c_[rad * np.cos(ang), rad * np.sin(ang)]


def polygon(n: int, r: float) -> np.ndarray:
    ang = np.arange(n) * 2 * np.pi / n
    return np.c_[r * np.cos(ang), r * np.sin(ang)]


def rotation_xyz(degrees: tuple[float, float, float]) -> np.ndarray:
    """Rotation matrix of extrinsic x, then y, then z turns (degrees)."""
    rx, ry, rz = np.radians(degrees)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return z @ y @ x


def baked(parts: list[Part], rotation: np.ndarray, scale: float) -> list[Part]:
    """The parts turned by ``rotation`` (3x3, about the origin) and scaled, offsets baked in."""
    out = []
    for p in parts:
        v = (p.vertices + np.asarray(p.offset)) @ rotation.T * scale
        out.append(Part(v, p.faces, p.uv, image=p.image, colors=p.colors, roughness=p.roughness, metallic=p.metallic))
    return out


def subdivide(parts: list[Part]) -> list[Part]:
    """Every triangle split in four at its edge midpoints (positions, UVs and colours interpolated): the
    same surface with another tessellation, as a re-meshed export of one scan."""
    out = []
    for p in parts:
        f = p.faces
        edges = np.sort(np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = len(p.vertices) + inv.reshape(3, -1).T  # per face: midpoints of (0,1), (1,2), (2,0)
        v = np.vstack([p.vertices, (p.vertices[uniq[:, 0]] + p.vertices[uniq[:, 1]]) / 2])
        uv = np.vstack([p.uv, (p.uv[uniq[:, 0]] + p.uv[uniq[:, 1]]) / 2])
        colors = None
        if p.colors is not None:
            c = p.colors.astype(np.int32)
            colors = np.vstack([p.colors, ((c[uniq[:, 0]] + c[uniq[:, 1]]) // 2).astype(np.uint8)])
        a, b, c3 = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
        faces = np.vstack([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c3], np.c_[ab, bc, ca]])
        out.append(Part(v, faces, uv, image=p.image, colors=colors, roughness=p.roughness, metallic=p.metallic,
                        offset=p.offset))
    return out


def recolour(parts: list[Part], hue_shift: float) -> list[Part]:
    """The parts in another look, same shape: a texture's hue turned by ``hue_shift`` (saturation raised),
    vertex colours inverted."""
    out = []
    for p in parts:
        q = Part(p.vertices, p.faces, p.uv, roughness=p.roughness, metallic=p.metallic, offset=p.offset)
        if p.image is not None:
            hsv = np.asarray(p.image.convert("HSV")).copy()
            hsv[..., 0] = (hsv[..., 0].astype(np.int32) + int(hue_shift * 255)) % 256
            hsv[..., 1] = np.maximum(hsv[..., 1], 120)  # make even white objects visibly coloured
            q.image = Image.fromarray(hsv, "HSV").convert("RGB")
        else:
            cols = p.colors.copy()  # type: ignore[union-attr]
            cols[:, :3] = 255 - cols[:, :3]  # inverted colours: a different look, same shape
            q.colors = cols
        out.append(q)
    return out
