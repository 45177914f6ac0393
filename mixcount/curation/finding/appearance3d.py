"""Orientation-free, scale-free appearance of a model, measured on its surface (numpy; no renderer).

A canonical render shows an object from one fixed camera, so the same scan stored lying on its side,
turned, or with another up axis looks different there. This descriptor does not depend on how the model
happens to be oriented or scaled:

* **Surface samples**: ``N`` points drawn area-weighted from every part (node transforms applied), each
  with its base colour: ``baseColorFactor x texture(uv) x COLOR_0`` for glTF materials, vertex or face
  colours, or the material colour. Texture resolution, UV layout and tessellation do not matter; only the
  colour that lies on the surface.
* **Colour histogram**: a soft (trilinear) 6x6x6 RGB histogram of the samples; distance = total variation,
  after :func:`exposure_gain` (one bounded brightness factor) brought the second model to the first's
  mean luminance: a re-baked texture is often lit or exposed differently.
* **Principal-frame colour layout** ("views aligned to the principal axes"): the samples are expressed in
  their principal axes (PCA of positions) and scaled by the extent along each axis, so a rotated,
  rescaled or re-tessellated copy lands in the same frame. Where the shape leaves the frame open (equal
  principal moments: a can's cross-section, a ball, a cube), the colour decides it: the axes of the
  colour-weighted second moment, else the direction of the colour-weighted first moment. Signs come
  from the shape's skewness. Whatever stays ambiguous (a sign, the order of two nearly equal axes, which
  colour moment decides) is enumerated: one grid per candidate frame. Each grid is 6x6x6 cells of summed
  colour and sample count, box-blurred over 3x3x3 cells; distance = the count-weighted mean absolute
  colour difference over cells either model covers (a cell only one covers counts 1, a cell both cover
  at least by how unevenly they cover it), minimised over the candidate frames of one side. A pair still apart whose
  shape leaves axes open gets a rotation search. The distances between two looks' grids (layout,
  pattern, axis-normalised shape) are :mod:`mixcount.curation.finding.colour_layout`.

Samples are cached (``.npz`` per content hash); grids are built only when a pair needs them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mixcount.atomic import atomic_path
from mixcount.catalog.materials import base_colour_factor, base_colour_texture, material_vertex_colours
from mixcount.curation.finding import portable_linalg as L
from mixcount.curation.finding.descriptors import face_areas
from mixcount.frame import load_model

APPEARANCE_VERSION = "look3d-v3"  # the surface samples (v3: node transforms without BLAS; v2: textures outside the model's folder read)
SEED = 20240611
N_SAMPLES = 6000
HIST_BINS = 6
GRID = 6
EIGEN_TIE = 0.10  # principal moments within 10 % of each other leave their axes to the colour
MOMENT_MIN = 0.02  # a colour first moment this weak (relative) gives no axis direction
SKEW_MIN = 0.05  # |skewness| below this does not fix a sign


def _colour_directions(n: int = 24) -> np.ndarray:
    """Fixed unit directions in RGB for the sliced colour transport: the three channels, grey, and
    ``n - 4`` more from a fixed seed (a sign does not matter for a 1-D transport)."""
    rest = np.random.default_rng(SEED).normal(size=(n - 4, 3))
    dirs = np.vstack([np.eye(3), np.ones((1, 3)), rest])
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


COLOUR_DIRECTIONS = _colour_directions()
COLOUR_QUANTILES = 128


def colour_quantiles(colours: np.ndarray) -> np.ndarray:
    """(COLOUR_QUANTILES, directions): the colours projected on :data:`COLOUR_DIRECTIONS`, sorted, read
    at the centres of ``COLOUR_QUANTILES`` equal shares (order statistics, no interpolation)."""
    proj = np.sort(COLOUR_DIRECTIONS @ np.clip(colours, 0.0, 1.0).T, axis=1)  # rows contiguous: a fast sort
    at = ((np.arange(COLOUR_QUANTILES) + 0.5) / COLOUR_QUANTILES * proj.shape[1]).astype(int).clip(0, proj.shape[1] - 1)
    return proj[:, at].T


@dataclass
class SurfaceLook:
    """A model's coloured surface samples; colour summaries and principal-frame colour grids on demand
    (most pairs differ in shape first, so most are never built)."""

    points: np.ndarray  # centred samples
    colours: np.ndarray
    basis: np.ndarray  # principal axes (columns), moments descending
    tied: list[list[int]]  # groups of nearly equal principal moments (2 * EIGEN_TIE)
    symmetric_axes: int  # how many axes the shape alone left open (EIGEN_TIE)
    _grids: np.ndarray | None = None
    _hist: np.ndarray | None = None
    _quantiles: np.ndarray | None = None

    @property
    def colour_hist(self) -> np.ndarray:
        """(HIST_BINS**3,) soft RGB histogram, sums to 1."""
        if self._hist is None:
            self._hist = colour_histogram(self.colours)
        return self._hist

    @property
    def quantiles(self) -> np.ndarray:
        """:func:`colour_quantiles` of the colours (the sliced colour transport)."""
        if self._quantiles is None:
            self._quantiles = colour_quantiles(self.colours)
        return self._quantiles

    @property
    def grids(self) -> np.ndarray:
        """(frames, GRID, GRID, GRID, 4): summed RGB and counts per cell, blurred; one per candidate
        frame. Built the first time a pair needs them."""
        if self._grids is None:
            frames, _ = principal_frames(self.points, self.colours)
            self._grids = colour_grids(self.points, self.colours, frames)
        return self._grids

    @property
    def frames(self) -> int:
        return len(self.grids)


# --------------------------------------------------------------------------- sampling


def _part_colours(geom: Any, faces: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Base colour (0..1) at barycentric points ``bary`` of ``faces`` of one trimesh geometry."""
    import trimesh

    n = len(faces)
    visual = geom.visual
    tri = np.asarray(geom.faces)[faces]
    if isinstance(visual, trimesh.visual.TextureVisuals):
        colour = np.tile(base_colour_factor(visual), (n, 1))
        vc = material_vertex_colours(visual, len(geom.vertices))
        if vc is not None:
            colour *= np.einsum("nk,nkc->nc", bary, vc[tri])
        texture = base_colour_texture(visual)
        uv = getattr(visual, "uv", None)
        if texture is not None and uv is not None and len(uv) == len(geom.vertices):
            pts = np.einsum("nk,nkd->nd", bary, np.asarray(uv, dtype=np.float64)[tri])
            h, w = texture.shape[:2]
            x = np.mod(pts[:, 0], 1.0) * (w - 1)
            y = (1.0 - np.mod(pts[:, 1], 1.0)) * (h - 1)  # trimesh flips glTF's V on load
            # only the sampled texels to float: a 4K texture whole in float64 was 400 MB (issue 69)
            colour *= texture[y.round().astype(int), x.round().astype(int)].astype(np.float64) / 255.0
        return np.clip(colour, 0.0, 1.0)
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.defined:
        if visual.kind == "face":
            return np.asarray(visual.face_colors, dtype=np.float64)[faces, :3] / 255.0
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        return np.einsum("nk,nkc->nc", bary, vc[tri])
    return np.full((n, 3), 0.7)  # no colour information: a neutral grey


def surface_samples(model_path: str | Path, *, n: int = N_SAMPLES, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """``n`` area-weighted surface points (model units, any frame) and their base colours (0..1).

    glTF/OBJ/PLY/STL through trimesh with node transforms; USD through the ingest loader, coloured grey
    (USD shading networks are not read here)."""
    import trimesh

    path = Path(model_path)
    rng = np.random.default_rng(seed)
    if path.suffix.lower() in (".usd", ".usda", ".usdc", ".usdz"):
        from mixcount.catalog.mesh import load_normalised

        mesh = load_normalised(path).mesh
        geoms = [(mesh, np.eye(4))]
    else:
        scene = load_model(path, force="scene")
        geoms = []
        for node in scene.graph.nodes_geometry:
            transform, name = scene.graph[node]
            geom = scene.geometry.get(name)
            if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
                geoms.append((geom, np.asarray(transform, dtype=np.float64)))
    if not geoms:
        raise ValueError("model has no faces")
    areas, tris = [], []
    for geom, transform in geoms:
        v = np.asarray(geom.vertices, dtype=np.float64)
        if not np.array_equal(transform, np.eye(4)):  # placed without BLAS: the same bits on every machine
            v = L.turn(v, transform[:3, :3]) + transform[:3, 3]
        t = v[np.asarray(geom.faces)]
        tris.append(t)
        areas.append(face_areas(t))
    flat = np.concatenate(areas)
    if not flat.sum() > 0:
        raise ValueError("model has zero surface area")
    cum = np.cumsum(flat) / flat.sum()  # stratified over the cumulative area, as the shape samples
    which = np.searchsorted(cum, (np.arange(n) + rng.random(n)) / n).clip(0, len(flat) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.c_[1 - s, s * (1 - r2), s * r2]
    offsets = np.cumsum([0] + [len(a) for a in areas])
    points = np.empty((n, 3))
    colours = np.empty((n, 3))
    for k, (geom, _) in enumerate(geoms):
        sel = np.nonzero((which >= offsets[k]) & (which < offsets[k + 1]))[0]
        if not len(sel):
            continue
        local = which[sel] - offsets[k]
        points[sel] = np.einsum("nk,nkd->nd", bary[sel], tris[k][local])
        colours[sel] = _part_colours(geom, local, bary[sel])
    return points, colours


def load_samples(model_path: str, *, cache_dir: Path | None, key: str | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surface_samples`, cached as ``cache_dir/<key>_<version>.npz``. The samples are stored as float32, so
    they are returned as float32 values (in float64) when first computed too: a cold run and a warm one (and
    two catalogs sharing the cache, one cold) see the same samples and get the same figures (issue 69)."""
    cache = cache_dir / f"{key}_{APPEARANCE_VERSION}.npz" if cache_dir is not None and key else None
    if cache is not None and cache.is_file():
        try:
            with np.load(cache) as data:
                return data["points"].astype(np.float64), data["colours"].astype(np.float64)
        except (OSError, ValueError, KeyError):
            pass
    points, colours = (a.astype(np.float32) for a in surface_samples(model_path))
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(cache) as tmp:
            np.savez_compressed(tmp, points=points, colours=colours)
    return points.astype(np.float64), colours.astype(np.float64)


# --------------------------------------------------------------------------- the descriptor


def colour_histogram(colours: np.ndarray, bins: int = HIST_BINS) -> np.ndarray:
    """Soft (trilinear) RGB histogram, normalised: a colour near a bin edge splits between bins."""
    x = np.clip(colours, 0.0, 1.0) * (bins - 1)
    lo = np.floor(x).astype(int).clip(0, bins - 2)
    frac = x - lo
    hist = np.zeros(bins ** 3)
    for corner in itertools.product((0, 1), repeat=3):
        c = np.asarray(corner)
        w = np.prod(np.where(c == 1, frac, 1.0 - frac), axis=1)
        idx = ((lo + c) * np.array([bins * bins, bins, 1])).sum(axis=1)
        np.add.at(hist, idx, w)
    return hist / max(hist.sum(), 1e-12)


LUMA = np.array([0.2126, 0.7152, 0.0722])


def _colour_weight(colours: np.ndarray) -> np.ndarray:
    """One signed number per sample: its colour along the main direction of colour variation,
    oriented to correlate positively with brightness; scaled to a mean magnitude of 1."""
    c = colours - colours.mean(axis=0)
    if not np.any(np.abs(c) > 1e-9):
        return np.zeros(len(colours))
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    axis = vt[0]
    lum = float(axis @ LUMA)
    if lum < -1e-6 or (abs(lum) <= 1e-6 and axis.sum() < 0):
        axis = -axis
    w = c @ axis
    return w / (float(np.abs(w).mean()) or 1.0)


def _tie_groups(eig: np.ndarray, tol: float) -> list[list[int]]:
    """Indices of eigenvalues (descending) grouped where neighbours are within ``tol`` (relative)."""
    groups = [[0]]
    for i in range(1, len(eig)):
        prev = eig[groups[-1][-1]]
        if prev > 0 and (prev - eig[i]) / prev < tol:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def _complete(d: np.ndarray) -> np.ndarray:
    """An orthonormal basis whose first column is ``d`` (the rest in a fixed, deterministic way)."""
    k = len(d)
    rest = np.linalg.svd(np.eye(k) - np.outer(d, d))[0][:, : k - 1]
    return np.c_[d, rest]


def _subspace_candidates(q: np.ndarray, w: np.ndarray, basis: np.ndarray) -> list[np.ndarray]:
    """Orientations of a (nearly) tied eigen-subspace to try: as the shape gives it (both orders when
    two-dimensional), by the colour-weighted second moment, by the colour-weighted first moment."""
    out = [basis]
    if basis.shape[1] == 2:
        out.append(basis[:, ::-1])
    proj = q @ basis
    scale = float(np.sqrt((proj ** 2).mean())) or 1.0
    m2 = (proj * w[:, None]).T @ proj / len(q) / scale ** 2
    vals, vecs = np.linalg.eigh(m2)
    out.append(basis @ vecs[:, np.argsort(vals)[::-1]])
    first = (proj * w[:, None]).mean(axis=0) / scale
    if np.linalg.norm(first) > MOMENT_MIN:
        out.append(basis @ _complete(first / np.linalg.norm(first)))
    return out


def principal_axes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal second moments (descending) and axes (columns) of a point set."""
    q = points - points.mean(axis=0)
    eig, vec = np.linalg.eigh(q.T @ q / len(q))
    order = np.argsort(eig)[::-1]
    return eig[order], vec[:, order]


def principal_frames(points: np.ndarray, colours: np.ndarray) -> tuple[list[np.ndarray], int]:
    """Candidate principal frames (3x3, columns = axes) of a coloured point set, and how many axes the
    shape alone left open (principal moments within EIGEN_TIE)."""
    q = points - points.mean(axis=0)
    eig, vec = principal_axes(points)
    w = _colour_weight(colours)
    open_axes = sum(len(g) for g in _tie_groups(eig, EIGEN_TIE) if len(g) > 1)
    # near ties (up to twice the tolerance) are enumerated, so two copies on either side of it still meet
    groups = _tie_groups(eig, 2 * EIGEN_TIE)
    options = [_subspace_candidates(q, w, vec[:, g]) if len(g) > 1 else [vec[:, g]] for g in groups]
    frames = []
    for choice in itertools.product(*options):
        basis = np.concatenate(choice, axis=1)
        signs = []
        for i in range(3):
            p = q @ basis[:, i]
            sd = float(p.std()) or 1.0
            skew = float((p ** 3).mean()) / sd ** 3
            signs.append((1 if skew > 0 else -1,) if abs(skew) > SKEW_MIN else (1, -1))
        for combo in itertools.product(*signs):
            frames.append(basis * np.asarray(combo))
    return frames, open_axes


def colour_grid(points: np.ndarray, colours: np.ndarray, frame: np.ndarray, size: int = GRID) -> np.ndarray:
    """Summed colour and count per cell of the frame-aligned bounding box (each axis scaled to 0..1),
    divided by the number of samples and box-blurred over 3x3x3 cells."""
    return colour_grids(points, colours, np.asarray(frame)[None], size)[0]


def colour_grids(points: np.ndarray, colours: np.ndarray, frames: np.ndarray | list[np.ndarray],
                 size: int = GRID, chunk: int = 64) -> np.ndarray:
    """:func:`colour_grid` for many frames at once, (frames, size, size, size, 4): one bincount per
    ``chunk`` frames instead of four per frame (a 600-rotation search in ~0.1 s, not ~2 s)."""
    from scipy.ndimage import uniform_filter

    frames = np.asarray(frames, dtype=np.float64).reshape(-1, 3, 3)
    centred = points - points.mean(axis=0)
    cells = size ** 3
    weights = np.c_[colours[:, :3], np.ones(len(points))]
    out = np.empty((len(frames), size, size, size, 4))
    for start in range(0, len(frames), chunk):
        block = frames[start:start + chunk]
        q = np.matmul(centred[None], block)  # (frames, n, 3)
        by_axis = np.ascontiguousarray(q.transpose(0, 2, 1))  # the same values; a reduction along contiguous memory
        lo, hi = by_axis.min(axis=2)[:, None, :], by_axis.max(axis=2)[:, None, :]  # is 14x faster than along axis 1
        u = (q - lo) / np.where(hi - lo > 0, hi - lo, 1.0)
        idx = np.clip((u * size).astype(int), 0, size - 1)
        flat = (idx[..., 0] * size + idx[..., 1]) * size + idx[..., 2] + (np.arange(len(block)) * cells)[:, None]
        grid = np.stack([np.bincount(flat.ravel(), weights=np.tile(weights[:, c], len(block)),
                                     minlength=cells * len(block)) for c in range(4)], axis=-1)
        out[start:start + len(block)] = grid.reshape(len(block), size, size, size, 4) / len(points)
    return uniform_filter(out, size=(1, 3, 3, 3, 1), mode="nearest")


def surface_look(points: np.ndarray, colours: np.ndarray) -> SurfaceLook:
    eig, basis = principal_axes(points)
    open_axes = sum(len(g) for g in _tie_groups(eig, EIGEN_TIE) if len(g) > 1)
    return SurfaceLook(points - points.mean(axis=0), colours, basis,
                       [g for g in _tie_groups(eig, 2 * EIGEN_TIE) if len(g) > 1], open_axes)


def exposure_gain(a: SurfaceLook, b: SurfaceLook, max_gain: float) -> float:
    """The one brightness factor that brings ``b``'s surface to ``a``'s mean luminance, bounded to
    ``[1 / max_gain, max_gain]``: a texture re-baked under other lighting or exposure is the same
    surface a few tens of percent darker or brighter, and a 6x6x6 histogram moves whole bins for 10 %.
    One factor for all channels, so a change of hue (a recolour, another print) is never absorbed."""
    la, lb = float(a.colours.mean(axis=0) @ LUMA), float(b.colours.mean(axis=0) @ LUMA)
    if la <= 1e-6 or lb <= 1e-6:
        return 1.0
    return float(np.clip(la / lb, 1.0 / max_gain, max_gain))


def relit(look: SurfaceLook, gain: float) -> SurfaceLook:
    """``look`` with its colours times ``gain`` <= 1 (darkening never clips, so the colour quantiles and
    any colour grids already built scale exactly); the frames are the same."""
    if not 0.0 < gain <= 1.0:
        raise ValueError(f"relit darkens only: gain {gain} is not in (0, 1]")
    if gain == 1.0:
        return look
    out = SurfaceLook(look.points, look.colours * gain, look.basis, look.tied, look.symmetric_axes)
    if look._quantiles is not None:
        out._quantiles = look._quantiles * gain
    if look._grids is not None:
        grids = look._grids.copy()
        grids[..., :3] *= gain
        out._grids = grids
    return out


def colour_transport(a: SurfaceLook, b: SurfaceLook, gain: float = 1.0) -> float:
    """Sliced 1-D earth mover's distance of the two surfaces' colour distributions (RGB in 0..1; the mean
    over :data:`COLOUR_DIRECTIONS` of the mean |quantile difference|), ``b``'s colours times ``gain``
    (for a gain above 1, ``a``'s divided by it instead: darkening never clips). Unlike a histogram it
    grows with how far colours moved, not with how many crossed a bin edge: a plain surface 2 % darker
    is about 0.02 away, not a whole bin."""
    if gain <= 1.0:
        return float(np.abs(a.quantiles - gain * b.quantiles).mean())
    return float(np.abs(a.quantiles / gain - b.quantiles).mean())


def colour_distance(a: SurfaceLook, b: SurfaceLook) -> float:
    """Total variation distance of the colour histograms, in [0, 1]."""
    return float(0.5 * np.abs(a.colour_hist - b.colour_hist).sum())
