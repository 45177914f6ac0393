"""A copy from another source in another *plain* colour (issue 34: the olive duck against the yellow one),
without bpy: the pair rule of ``catalog filter`` on surface samples and shape descriptors of real meshes.

* the cow scan (pymeshlab's sample) in yellow against itself in olive, flattened 20 % along one model
  axis, turned and in mm: ``possible_copy`` (the loose shape gates pass, the tight ones do not, the
  axis-normalised shape agrees);
* the same cow in red, turned and in mm, shape untouched: ``colour_variant`` (one geometry, two colours);
* two plain erasers (boxes) of other proportions in other colours: nothing, although their
  axis-normalised shapes are the same (every box is a cube once each axis is scaled): the mirror
  asymmetry gate keeps symmetric shape families out;
* the cow against the airplane scan (both mirror-asymmetric along two axes) in other plain colours: nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from mixcount.catalog.models import CatalogObject
from mixcount.config import load_config
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import colour_layout as CL
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding.copy_rules import pair_flags
from mixcount.curation.finding.filter_items import Item, LayoutCache
from mixcount.curation.flag_kinds import COLOUR_VARIANT, POSSIBLE_COPY

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"


def _rotation(deg: tuple[float, float, float]) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", deg, degrees=True).as_matrix()


def _item(oid: int, vertices: np.ndarray, faces: np.ndarray, rgb: tuple[int, int, int], tmp: Path) -> Item:
    """A catalog item as ``catalog filter`` builds it, from a GLB written to disk (one plain colour)."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(vertices), 1)))
    path = tmp / f"obj_{oid}.glb"
    mesh.export(path)
    points, colours = A.surface_samples(path)
    obj = CatalogObject(id=oid, name=f"obj {oid}", content_hash=f"{oid:032x}", geometry_hash=f"g{oid:031x}")
    shape = D.shape_descriptor(vertices, faces, watertight=False, volume=None, quality=False)
    return Item(obj, shape=shape, surface=A.surface_look(points, colours), appearance="vertex_color")


def _pairs(items: list[Item]) -> dict[frozenset[int], dict[str, str]]:
    th = load_config().filter
    out: dict[frozenset[int], dict[str, str]] = {}
    for f in pair_flags(items, th, LayoutCache(None)):
        assert f.b is not None
        out.setdefault(frozenset((f.a, f.b)), {})[f.kind] = f.reason
    return out


@pytest.fixture(scope="module")
def cow() -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(SAMPLES / "cow.obj", force="mesh")
    return np.asarray(mesh.vertices, dtype=np.float64) * 0.2, np.asarray(mesh.faces)


def test_plain_recolour_from_another_source(cow, tmp_path):
    v, f = cow
    flat = v * np.array([1.0, 0.8, 1.0])  # a re-export squashing the model's Y axis by 20 %
    items = [
        _item(1, v, f, (225, 190, 40), tmp_path),  # yellow
        _item(2, flat @ _rotation((90.0, 0.0, 30.0)).T * 1000.0, f, (110, 110, 40), tmp_path),  # olive, flat, mm
        _item(3, v @ _rotation((0.0, 30.0, 120.0)).T * 1000.0, f, (190, 50, 45), tmp_path),  # red, turned, mm
    ]
    pairs = _pairs(items)
    olive = pairs.get(frozenset((1, 2)), {})
    assert set(olive) == {POSSIBLE_COPY}, olive
    assert "each principal axis scaled to its extent" in olive[POSSIBLE_COPY]
    red = pairs.get(frozenset((1, 3)), {})
    assert set(red) == {COLOUR_VARIANT}, red
    assert "another plain colour" in red[COLOUR_VARIANT]
    # the loose shape gates alone do not explain it: the flattened copy fails the tight ones
    th = load_config().filter
    assert items[0].shape is not None and items[1].shape is not None
    assert D.moment_distance(items[0].shape, items[1].shape) > th.look_proportions


def test_symmetric_and_different_shapes_stay_apart(cow, tmp_path):
    v, f = cow
    plane = trimesh.load(SAMPLES / "airplane.obj", force="mesh")
    box_a = trimesh.creation.box((0.050, 0.021, 0.011))
    box_b = trimesh.creation.box((0.057, 0.023, 0.011))
    items = [
        _item(1, v, f, (225, 190, 40), tmp_path),
        _item(2, np.asarray(plane.vertices) * 0.1, np.asarray(plane.faces), (150, 155, 160), tmp_path),
        _item(3, np.asarray(box_a.vertices), np.asarray(box_a.faces), (240, 150, 170), tmp_path),  # pink eraser
        _item(4, np.asarray(box_b.vertices) @ _rotation((0.0, 0.0, 40.0)).T, np.asarray(box_b.faces),
              (245, 245, 245), tmp_path),  # white eraser, other proportions, turned
    ]
    # no pairing to decide; the two erasers (two boxes) are ranked as look-alikes, information only
    pairs = _pairs(items)
    assert pairs == {frozenset((3, 4)): {"look_alike": pairs[frozenset((3, 4))]["look_alike"]}}
    assert "a plain solid's shape" in pairs[frozenset((3, 4))]["look_alike"]
    th = load_config().filter
    # what keeps the erasers apart is the asymmetry gate: scaled per axis, two boxes are one shape
    assert CL.occupancy_distance(items[2].shape_look(), items[3].shape_look()) <= th.cross_source_occupancy
    assert sorted(items[2].asymmetry())[1] < th.cross_source_min_asymmetry
    assert not items[2].surface.tied and not items[3].surface.tied  # type: ignore[union-attr]
    # the cow and the airplane are both asymmetric enough; their axis-normalised shapes differ
    assert min(sorted(it.asymmetry())[1] for it in items[:2]) >= th.cross_source_min_asymmetry
    assert CL.occupancy_distance(items[0].shape_look(), items[1].shape_look()) > th.cross_source_occupancy
