"""The pieces of duplicate detection across sources, with known answers: the republishing tools of the demo
traps (remesh, re-bake, split, weld), the sliced colour transport and the bounded exposure factor, and the
fast D2 quantiles. Real meshes from the demo builders, real pymeshlab, no mocks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import descriptors as D
from mixcount.demo import library as L
from mixcount.demo import traps as T


def can():
    return L.build_can(0, np.random.default_rng(1))


def test_weld_merges_seams_and_keeps_the_surface():
    spec = can()
    v, f = T.weld(spec.parts)
    part = spec.parts[0]
    assert len(v) < len(part.vertices) and len(f) == len(part.faces)  # the revolve's seam column merged
    area = lambda vv, ff: T._triangle_areas(vv[ff]).sum()  # noqa: E731
    assert area(v, f) == pytest.approx(area(part.vertices, part.faces), rel=1e-9)


@pytest.mark.parametrize("method,target", [("isotropic", 6000), ("decimate", 120)])
def test_remesh_reaches_another_face_count_on_the_same_surface(method, target):
    v, f = T.weld(can().parts)
    nv, nf = T.remesh(v, f, method=method, target_faces=target)
    assert 0.5 * target < len(nf) < 2.0 * target and len(nf) != len(f)
    old = {tuple(x) for x in np.round(v, 9)}
    shared = sum(tuple(x) in old for x in np.round(nv, 9))
    if method == "isotropic":  # a new triangulation: mostly new vertices
        assert shared < 0.5 * len(nv)
    else:  # edge collapses keep a subset of the vertices (the can: 62 of its 182)
        assert len(nv) < 0.5 * len(v)
    assert np.allclose(np.ptp(nv, axis=0), np.ptp(v, axis=0), rtol=0.05)
    with pytest.raises(ValueError, match="unknown remesh method"):
        T.remesh(v, f, method="smooth", target_faces=10)


def test_atlas_cells_do_not_overlap():
    uv = T.atlas_layout(101, 512)
    assert uv.shape == (101, 3, 2) and uv.min() > 0 and uv.max() < 1
    centres = uv.mean(axis=1)
    assert len(np.unique(np.round(centres, 6), axis=0)) == 101  # every triangle its own place


def test_bake_carries_the_surface_colour_into_a_new_layout():
    spec = can()
    colour = T.surface_colour(spec.parts, seed=3)
    v, f = T.weld(spec.parts)
    baked = T.bake(v, f, colour, size=256)
    assert baked.image is not None and 230 <= baked.image.size[0] <= 256 and len(baked.faces) == len(f)
    # colour at each face centre, read through the new UVs, equals the original surface's colour there
    img = np.asarray(baked.image, dtype=np.float64)
    h, w = img.shape[:2]
    centre_uv = baked.uv[baked.faces].mean(axis=1)
    texel = img[((1 - centre_uv[:, 1]) * (h - 1)).round().astype(int), (centre_uv[:, 0] * (w - 1)).round().astype(int)]
    truth = colour.colour_at(baked.vertices[baked.faces].mean(axis=1)).astype(np.float64)
    assert np.median(np.abs(texel - truth).max(axis=1)) <= 2
    darker = T.bake(v, f, colour, size=256, gain=0.8)
    assert np.asarray(darker.image, dtype=float).mean() == pytest.approx(0.8 * img.mean(), rel=0.02)


def test_split_cuts_into_parts_with_their_own_origins():
    part = L.build_ball(0, np.random.default_rng(2)).parts[0]
    pieces = T.split(part, 5)
    assert len(pieces) == 5 and sum(len(p.faces) for p in pieces) == len(part.faces)
    offsets = np.array([p.offset for p in pieces])
    assert len(np.unique(np.round(offsets, 9), axis=0)) == 5
    for p in pieces:
        assert np.allclose(p.vertices.mean(axis=0), 0.0, atol=1e-12)  # each part centred on its own origin


def look(parts, tmp_path, name):
    path = tmp_path / f"{name}.glb"
    path.write_bytes(L.export_glb(parts))
    return A.surface_look(*A.surface_samples(path))


def test_colour_transport_and_exposure(tmp_path):
    spec = can()
    colour = T.surface_colour(spec.parts, seed=4)
    v, f = T.weld(spec.parts)
    base = look(spec.parts, tmp_path, "base")
    darker = look([T.bake(v, f, colour, size=512, gain=0.85)], tmp_path, "darker")
    beans = look(L.build_can(3, np.random.default_rng(4)).parts, tmp_path, "beans")
    recolour = look(L.recolour(spec.parts, 0.33), tmp_path, "recolour")
    gain = A.exposure_gain(base, darker, 1.25)
    assert gain == pytest.approx(1 / 0.85, rel=0.03)
    plain = A.colour_transport(base, darker)
    assert A.colour_transport(base, darker, gain) < 0.02 < plain  # one factor brings the re-bake back
    assert A.colour_distance(base, A.relit(base, 1.0)) == 0.0
    assert 0.8 <= A.exposure_gain(base, beans, 1.25) <= 1.25 and A.exposure_gain(base, base, 1.25) == 1.0
    for other in (beans, recolour):  # another print / a hue change is never absorbed by the factor
        g = A.exposure_gain(base, other, 1.25)
        assert min(A.colour_transport(base, other), A.colour_transport(base, other, g)) > 0.1
    with pytest.raises(ValueError, match="darkens only"):
        A.relit(base, 1.2)
    # relit scales quantiles and any grids already built exactly
    grids = base.grids
    half = A.relit(base, 0.5)
    assert np.allclose(half.quantiles, 0.5 * base.quantiles)
    assert np.allclose(half.grids[..., :3], 0.5 * grids[..., :3]) and np.allclose(half.grids[..., 3], grids[..., 3])


def test_d2_quantiles_match_numpy():
    pts = np.random.default_rng(0).random((1500, 3)) * [1.0, 2.0, 0.5]
    d = pdist(pts)
    exact = np.quantile(d / d.mean(), (np.arange(D.D2_QUANTILES) + 0.5) / D.D2_QUANTILES)
    assert np.abs(D.d2_quantiles(d) - exact).max() < 1e-4
    assert not D.d2_quantiles(np.zeros(10)).any()
