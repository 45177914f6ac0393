"""`catalog filter` on a real SQLite catalog of real GLB files (renders drawn with PIL, no bpy): each
flag kind with its pair, one kept object per duplicate group by the quality order, idempotent reruns,
a person's decision outranking flags, other areas' flags and exclusions left alone; and the
descriptors on meshes with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from sqlalchemy import select
from test_curate_support import library_catalog, quick_config

from mixcount.catalog.models import CatalogObject, Flag, ReviewDecision
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.curation.flag_kinds import DUPLICATE_KINDS, EXCLUDED_MARK, FILTER_KINDS


def state(catalog):
    with catalog.session() as s:
        flags = {(f.object_id, f.kind, f.pair_object_id) for f in s.scalars(select(Flag))}
        statuses = {o.id: o.status for o in s.scalars(select(CatalogObject))}
    return flags, statuses


def flags_of(catalog, oid):
    with catalog.session() as s:
        return {(f.kind, f.pair_object_id) for f in s.scalars(select(Flag).where(Flag.object_id == oid))}


def test_filter_flags_pairs_groups_and_quality_order(catalog, tmp_path):
    objs = library_catalog(catalog, tmp_path)
    ids = {k: o.id for k, o in objs.items()}
    summary = run_filter(catalog, quick_config())
    assert summary.ground_truth is None  # not a demo library
    assert summary.missing_renders == 0 and not summary.descriptor_failures

    assert ("exact_duplicate", ids["box_copy"]) in flags_of(catalog, ids["box"])
    assert ("exact_duplicate", ids["box"]) in flags_of(catalog, ids["box_copy"])
    # one geometry in other colours: a colour variant both ways, not a duplicate; both stay active
    assert ("colour_variant", ids["cyl_recolour"]) in flags_of(catalog, ids["cyl"])
    assert ("colour_variant", ids["cyl"]) in flags_of(catalog, ids["cyl_recolour"])
    assert not {k for k, _ in flags_of(catalog, ids["cyl"])} & set(DUPLICATE_KINDS)
    # two plain balls: a grey surface and a sphere carry no evidence that they are one object (issue 57):
    # a look-alike for information, never an exclusion
    assert ("look_alike", ids["ball"]) in flags_of(catalog, ids["ball_big"])
    assert not {k for k, _ in flags_of(catalog, ids["ball_big"])} & set(DUPLICATE_KINDS)
    assert ("near_duplicate_geometry", ids["ball"]) not in flags_of(catalog, ids["ball_big"])  # different size
    assert ("degenerate", None) in flags_of(catalog, ids["flat"])
    assert ("size_outlier", None) in flags_of(catalog, ids["giant"])
    for clean in ("cone", "capsule", "ring"):  # nothing to decide (a look-alike is information only)
        assert {k for k in flags_of(catalog, ids[clean]) if k[0] != "look_alike"} == set(), clean

    _, status = state(catalog)
    # lower id wins a tie; an image-textured object beats a vertex-coloured one whatever the ids
    keep_box = min(ids["box"], ids["box_copy"])
    assert status[keep_box] == "active" and status[ids["box"] + ids["box_copy"] - keep_box] == "excluded"
    assert status[ids["cyl_recolour"]] == "active" and status[ids["cyl"]] == "active"
    assert status[ids["flat"]] == "excluded"  # degenerate, filter.exclude_degenerate
    assert status[ids["giant"]] == "active"  # size outliers are flagged, not excluded
    with catalog.session() as s:
        reason = s.scalar(select(Flag.reason).where(Flag.object_id == ids["cyl"], Flag.kind == "colour_variant"))
        dropped = s.scalar(select(Flag.reason).where(Flag.object_id == ids["box"] + ids["box_copy"] - keep_box))
    assert reason.startswith("colour variant: same shape and size") and "D2" in reason and "colours differ" in reason
    assert EXCLUDED_MARK not in reason and f"#{ids['cyl_recolour']}" in reason
    assert EXCLUDED_MARK in dropped and f"#{keep_box}" in dropped


def test_filter_idempotent_review_outranks_and_foreign_state_kept(catalog, tmp_path):
    objs = library_catalog(catalog, tmp_path)
    ids = {k: o.id for k, o in objs.items()}
    cfg = quick_config()
    first = run_filter(catalog, cfg)
    before = state(catalog)
    keep_box, drop_box = sorted((ids["box"], ids["box_copy"]))
    assert before[1][drop_box] == "excluded"
    second = run_filter(catalog, cfg)
    assert state(catalog) == before
    assert second.reactivated == first.excluded and second.excluded == first.excluded

    # another area's flag and exclusion (captioning) survive; a person's decisions win over the flags
    with catalog.session() as s:
        s.add(Flag(object_id=ids["cone"], kind="caption_collision", score=1.0, reason="same caption", pair_object_id=ids["ring"]))
        s.get(CatalogObject, ids["capsule"]).status = "excluded"  # excluded by someone else, no filter mark
        s.add(ReviewDecision(object_id=drop_box, decision="accept", reviewer="ana"))  # the filter excluded it
        s.add(ReviewDecision(object_id=ids["ring"], decision="reject", reviewer="ana"))  # clean but rejected
        s.commit()
    run_filter(catalog, cfg)
    flags, status = state(catalog)
    assert (ids["cone"], "caption_collision", ids["ring"]) in flags
    assert status[ids["capsule"]] == "excluded"
    assert status[drop_box] == "active" and status[keep_box] == "excluded"  # accepted one is the keeper
    assert status[ids["ring"]] == "excluded"
    assert {f for f in flags if f[1] in FILTER_KINDS} == {f for f in before[0] if f[1] in FILTER_KINDS}

    # a later decision replaces an earlier one
    with catalog.session() as s:
        s.add(ReviewDecision(object_id=drop_box, decision="reject", reviewer="ben"))
        s.commit()
    run_filter(catalog, cfg)
    assert state(catalog)[1][drop_box] == "excluded"
    assert state(catalog)[1][keep_box] == "active"


def test_shape_descriptor_known_answers():
    def desc(mesh):
        return D.shape_descriptor(mesh.vertices, mesh.faces, watertight=mesh.is_watertight, volume=None)

    cyl = desc(trimesh.creation.cylinder(radius=0.3, height=2.0, sections=48))
    cyl_coarse = desc(trimesh.creation.cylinder(radius=0.3, height=2.0, sections=24))
    cyl_scaled = desc(trimesh.creation.cylinder(radius=0.9, height=6.0, sections=48))
    cyl_fat = desc(trimesh.creation.cylinder(radius=0.36, height=2.0, sections=48))
    box = desc(trimesh.creation.box((1, 1, 1)))
    box_tall = desc(trimesh.creation.box((1, 1, 1.05)))
    ico, uv = desc(trimesh.creation.icosphere(4)), desc(trimesh.creation.uv_sphere(1, (40, 40)))
    th = quick_config().filter
    assert D.d2_distance(cyl, cyl_scaled) < 1e-9 and D.ratio_distance(cyl, cyl_scaled) < 1e-9  # scale-free
    assert D.size_ratio(cyl_scaled, cyl) == pytest.approx(3.0)
    assert D.d2_distance(ico, uv) < th.geometry_d2 and D.ratio_distance(ico, uv) < th.geometry_proportions
    assert D.d2_distance(cyl, cyl_coarse) < th.geometry_d2
    assert D.d2_distance(cyl, cyl_fat) > th.geometry_d2 or D.ratio_distance(cyl, cyl_fat) > th.geometry_proportions
    assert D.ratio_distance(box, box_tall) > th.geometry_proportions  # D2 hardly sees 5 %; proportions do
    assert D.d2_distance(box, ico) > 2 * th.geometry_d2


def test_a_one_part_mesh_counts_the_same_crossings_as_a_part_of_an_assembly():
    """The one-part shortcut of ``self_intersection_fraction`` (the mesh as it is) and the per-part path
    (each connected part renumbered) count the same crossing faces; other parts never cross it."""
    poked = trimesh.creation.icosphere(2)
    v = np.asarray(poked.vertices).copy()
    v[0] *= -1.6  # one vertex pushed through the far side: its faces cross the sphere's
    f = np.asarray(poked.faces)
    alone = D.self_intersection_fraction(v, f)
    assert 0 < alone < 0.2
    far = trimesh.creation.box((0.5, 0.5, 0.5)).subdivide()  # 48 faces, away from the sphere
    v2 = np.vstack([v, np.asarray(far.vertices) + [10.0, 0.0, 0.0]])
    f2 = np.vstack([f, np.asarray(far.faces) + len(v)])
    assembled = D.self_intersection_fraction(v2, f2)
    assert round(alone * len(f)) == round(assembled * len(f2))
    overlapping = np.vstack([v, np.asarray(far.vertices)])  # the box inside the sphere: another part, not a defect
    assert D.self_intersection_fraction(overlapping, f2) == assembled
    # the shape descriptor's shared edge counts and areas: the same fractions as alone
    desc = D.shape_descriptor(v, f, watertight=False, volume=None)
    assert desc.nonmanifold_fraction == round(D.nonmanifold_fraction(f), 6)
    assert desc.boundary_fraction == round(D.boundary_fraction(f), 6) == 0.0
    assert desc.area_m2 == pytest.approx(float(D.face_areas(v[f]).sum()))


def test_nonmanifold_fraction_and_phash():
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])  # edge (0, 1) shared by three faces
    assert D.nonmanifold_fraction(faces) == pytest.approx(1 / 7)
    assert D.nonmanifold_fraction(trimesh.creation.icosphere(2).faces) == 0.0
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(np.random.default_rng(0).uniform(0, 255, (32, 32)), 3)
    assert D.phash_bits(img) == D.phash_bits(img * 0.5 + 20)  # brightness/contrast changes keep the hash
    assert bin(D.phash_bits(img) ^ D.phash_bits(img.T[::-1])).count("1") > 16
