"""Curation on capture-like inputs, real files in a real SQLite catalog, no renders needed:

* duplicates that survive changes of scale, orientation / up axis, tessellation and source are flagged
  with their pair by the orientation-free rule, while different objects of one shape family (two balls,
  two mugs, two cans) stay apart;
* "degenerate means unusable": a clean non-manifold, open object stays active with a scored
  ``mesh_quality`` warning; a single-sided plane is degenerate; self-intersections inside one part are
  measured, parts that overlap each other are not;
* the surface-appearance descriptor's known answers (rotation, scale, tessellation, cubes)."""

from __future__ import annotations

import json
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest
import trimesh
from sqlalchemy import select
from test_curate_support import quick_config

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import colour_layout as CL
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.curation.finding.quality_flags import mesh_quality_score
from mixcount.curation.flag_kinds import severity
from mixcount.demo import library as L
from mixcount.demo import traps as T

pytestmark = pytest.mark.slow  # capture-sized meshes through ingest and filter: not in the fast tier


def write(root, folder, parts):
    path = root / folder
    path.mkdir(parents=True)
    (path / "model.glb").write_bytes(L.export_glb(parts))


def capture_library(root):
    """Originals, their transformed copies, and same-family objects that must stay apart."""
    can = L.build_can(0, np.random.default_rng(1))
    ball = L.build_ball(0, np.random.default_rng(2))  # tennis
    die = L.build_die(0, np.random.default_rng(3))  # a cube: principal axes left to the colour
    write(root, "can", can.parts)
    write(root, "can_turned", L.baked(can.parts, L.rotation_xyz((90.0, 0.0, 37.0)), 2.0))  # other up axis, 2x
    write(root, "ball", ball.parts)
    write(root, "ball_retessellated", L.subdivide(ball.parts))
    write(root, "die", die.parts)
    write(root, "die_turned_retessellated", L.subdivide(L.baked(die.parts, L.rotation_xyz((0.0, 90.0, 45.0)), 0.7)))
    other = root / "can_scan"
    other.mkdir()
    L.export_obj(can.parts, other, scale=125.0)  # centimetres, 1.25x, Z-up read as Y-up
    (other / "metadata.json").write_text(json.dumps({"name": "cola can scan", "category": "can", "units": "cm"}))
    # the same shape families, other objects
    write(root, "can_other", L.build_can(3, np.random.default_rng(4)).parts)  # beans, same shape family
    write(root, "ball_golf", L.build_ball(1, np.random.default_rng(5)).parts)
    write(root, "ball_soccer", L.build_ball(4, np.random.default_rng(6)).parts)
    write(root, "mug_white", L.build_mug(0, np.random.default_rng(7)).parts)
    write(root, "mug_navy", L.build_mug(1, np.random.default_rng(8)).parts)
    write(root, "tote", L.build_tote(np.random.default_rng(9)).parts)  # non-manifold and open, usable
    plane = trimesh.Trimesh(vertices=[[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    (root / "sheet").mkdir()
    plane.export(root / "sheet" / "model.glb")
    return root


def test_duplicates_survive_transforms_and_families_stay_apart(catalog, tmp_path):
    lib = capture_library(tmp_path / "lib")
    summary = ingest_paths(catalog, [lib], config=quick_config("ingest.workers=2"))
    assert summary.broken == 0, summary.broken_objects
    result = run_filter(catalog, quick_config())
    assert not result.descriptor_failures
    with catalog.session() as s:
        folder = {o.id: Path(o.model_path).parent.name for o in s.scalars(select(CatalogObject))}
        status = {folder[o.id]: o.status for o in s.scalars(select(CatalogObject))}
        flags = s.scalars(select(Flag)).all()
    # the pairs to decide (look-alikes of one shape family are information only, issue 49)
    pairs = {frozenset((folder[f.object_id], folder[f.pair_object_id])): f for f in flags
             if f.pair_object_id and severity(f.kind, f.reason) == "decide"}
    assert {f.kind for f in flags if f.pair_object_id and severity(f.kind, f.reason) == "info"} <= {"look_alike"}
    expected = {frozenset(p) for p in (("can", "can_turned"), ("can", "can_scan"), ("can_turned", "can_scan"),
                                       ("ball", "ball_retessellated"), ("die", "die_turned_retessellated"))}
    assert set(pairs) == expected, sorted(sorted(p) for p in pairs)
    for pair in expected:
        assert pairs[pair].kind in ("near_duplicate_appearance", "near_duplicate_geometry"), pair
    assert "same surface colours and layout from every side" in pairs[frozenset(("can", "can_turned"))].reason
    # one object kept per group
    for group in (("can", "can_turned", "can_scan"), ("ball", "ball_retessellated"), ("die", "die_turned_retessellated")):
        assert sorted(status[g] for g in group).count("active") == 1, group
    quality = {(folder[f.object_id], f.kind): f for f in flags if f.pair_object_id is None}
    tote = quality[("tote", "mesh_quality")]
    assert status["tote"] == "active" and ("tote", "degenerate") not in quality
    assert 0.3 < tote.score <= 1.0 and "non-manifold edges" in tote.reason and "open edges" in tote.reason
    assert ("sheet", "degenerate") in quality and "flat beyond repair" in quality[("sheet", "degenerate")].reason
    assert status["sheet"] == "excluded"

    # exclude_mesh_quality excludes the tote (score over the bar); the default never does
    run_filter(catalog, quick_config("filter.exclude_mesh_quality=true", "filter.mesh_quality_exclude_score=0.3"))
    with catalog.session() as s:
        assert {folder[o.id]: o.status for o in s.scalars(select(CatalogObject))}["tote"] == "excluded"
    run_filter(catalog, quick_config())
    with catalog.session() as s:
        assert {folder[o.id]: o.status for o in s.scalars(select(CatalogObject))}["tote"] == "active"


def test_mesh_quality_facts():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    assert D.boundary_fraction(box.faces) == 0.0 and D.self_intersection_fraction(box.vertices, box.faces) == 0.0
    open_box = box.faces[2:]  # one face of the box missing: a hole
    assert D.boundary_fraction(open_box) == pytest.approx(4 / 17)  # the 4 rim edges of 17 (diagonal gone)
    # two boxes pushed into each other: an assembly, not a self-intersection
    both = trimesh.util.concatenate([box, box.copy().apply_translation([0.05, 0.0, 0.0])])
    assert D.self_intersection_fraction(both.vertices, both.faces) == 0.0
    # one connected part folded through itself: the crossing faces are counted
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    v = np.array(ball.vertices)
    v[v[:, 2] > 0.01, 2] -= 0.08  # push the upper cap down through the lower half
    folded = trimesh.Trimesh(v, ball.faces, process=False)
    assert 0 < D.self_intersection_fraction(folded.vertices, folded.faces) < 1
    assert mesh_quality_score(0.0) == 0.0 and mesh_quality_score(0.001) == pytest.approx(0.1003, abs=1e-3)
    assert mesh_quality_score(0.01) == pytest.approx(0.3471, abs=1e-3) and mesh_quality_score(1.0) == 1.0


def test_surface_look_known_answers(tmp_path):
    can = L.build_can(0, np.random.default_rng(1))
    other = L.build_can(3, np.random.default_rng(4))

    def look(parts, name):
        path = tmp_path / f"{name}.glb"
        path.write_bytes(L.export_glb(parts))
        return A.surface_look(*A.surface_samples(path))

    base = look(can.parts, "a")
    turned = look(L.baked(can.parts, L.rotation_xyz((90.0, 0.0, 37.0)), 3.0), "b")
    finer = look(L.subdivide(can.parts), "c")
    beans = look(other.parts, "d")
    assert A.colour_distance(base, turned) < 1e-9 and CL.layout_distance(base, turned) < 1e-6  # same samples, turned
    assert A.colour_distance(base, finer) < 0.02 and CL.layout_distance(base, finer, search_above=0.06) < 0.04
    assert A.colour_distance(base, beans) > 0.3 and CL.layout_distance(base, beans, search_above=0.06) > 0.1
    hist = A.colour_histogram(np.array([[0.1, 0.5, 0.9]] * 10))
    assert hist.sum() == pytest.approx(1.0) and (hist > 0).sum() == 8  # soft: a colour between bins splits


SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"  # real scans pymeshlab ships


def real_scan(name: str) -> L.Part:
    """A textured OBJ scan (pymeshlab's sample bunny) as one demo part, in its own units and frame."""
    mesh = trimesh.load(SAMPLES / name, force="mesh", process=False)
    image = mesh.visual.material.image.convert("RGB")
    return L.Part(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces), np.asarray(mesh.visual.uv),
                  image=image, roughness=0.7)


def ids_by_folder(catalog):
    with catalog.session() as s:
        objs = s.scalars(select(CatalogObject)).all()
        folder = {o.id: Path(o.model_path).parent.name for o in objs}
        flags = s.scalars(select(Flag)).all()
    return folder, flags


def test_real_scan_republished_by_other_sources_is_paired(catalog, tmp_path):
    """The Stanford bunny scan (10k faces, image texture) against three copies another source could have
    published, each different in several ways at once, and against a recolour of itself and another scan:

    * remeshed isotropically to ~3x the faces, texture re-baked, turned, stored in millimetres (x1000);
    * decimated to a quarter, re-baked at a quarter of the resolution 15 % darker, turned, x0.001;
    * re-baked, cut into four parts with their own origins, turned the other way up (a Y-up/Z-up mix-up).

    All four are one duplicate group; the recolour (another print of one model, same size) is a colour
    variant (geometry rule, other colours), active; the cow stays apart."""
    lib = tmp_path / "lib"
    bunny = real_scan("bunny10k_textured.obj")
    turn = L.rotation_xyz
    copies = {
        "bunny": [bunny],
        "bunny_remeshed_mm": T.republish([bunny], method="isotropic", target_faces=30_000, texture_px=1024,
                                         rotation=turn((30.0, 60.0, 10.0)), scale=1000.0, seed=1),
        "bunny_decimated_small": T.republish([bunny], method="decimate", target_faces=2_500, texture_px=128, gain=0.85,
                                             rotation=turn((-90.0, 0.0, 200.0)), scale=0.001, seed=2),
        "bunny_split": T.republish([bunny], method=None, target_faces=0, texture_px=512, pieces=4,
                                   rotation=turn((90.0, 0.0, 0.0)), scale=1.0, seed=3),
        "bunny_recoloured": L.recolour([bunny], 0.4),
    }
    for name, parts in copies.items():
        write(lib, name, parts)
    cow = trimesh.load(SAMPLES / "cow.obj", force="mesh")
    write(lib, "cow", [L.Part(np.asarray(cow.vertices), np.asarray(cow.faces), np.zeros((len(cow.vertices), 2)),
                              colors=np.full((len(cow.vertices), 4), 200, np.uint8))])
    summary = ingest_paths(catalog, [lib], config=quick_config("ingest.workers=2"))
    assert summary.broken == 0, summary.broken_objects
    result = run_filter(catalog, quick_config())
    assert not result.descriptor_failures
    folder, flags = ids_by_folder(catalog)
    pairs: dict[frozenset, set[str]] = {}
    for f in flags:
        if f.pair_object_id is not None:
            pairs.setdefault(frozenset((folder[f.object_id], folder[f.pair_object_id])), set()).add(f.kind)
    scans = ("bunny", "bunny_remeshed_mm", "bunny_decimated_small", "bunny_split")
    for a, b in combinations(scans, 2):
        assert "near_duplicate_appearance" in pairs.get(frozenset((a, b)), set()), (a, b, sorted(map(sorted, pairs)))
    recolour = {p: k for p, k in pairs.items() if "bunny_recoloured" in p}
    # same mesh, same size, other colours: a colour variant; against the republished copies (remeshed,
    # another size) only the repeating colour pattern is left: a possible copy for a person
    assert recolour and all(k in ({"colour_variant"}, {"possible_copy"}) for k in recolour.values()), recolour
    assert recolour[frozenset(("bunny", "bunny_recoloured"))] == {"colour_variant"}
    assert not any("cow" in p for p in pairs)
    exposure = [f.reason for f in flags if f.kind == "near_duplicate_appearance"
                and {folder[f.object_id], folder[f.pair_object_id]} == {"bunny", "bunny_decimated_small"}]
    assert exposure and "exposure x" in exposure[0]


def test_capture_sized_scan_pairs_with_its_remeshed_scaled_turned_copy(catalog, tmp_path, capsys):
    """A 300k-face textured scan against its copy remeshed by pymeshlab (a fifth of the faces), texture
    re-baked, x0.01 and turned: one pair, found by the orientation-free rule. The time per pair (both
    descriptors computed cold, then the comparison) is printed."""
    import time

    from mixcount.catalog.step_executor import InThisProcess
    from mixcount.curation.finding import catalog_filter as F
    from mixcount.curation.finding.copy_rules import pair_flags
    from mixcount.curation.finding.filter_items import Item

    scan = T.scan_like(300_000, np.random.default_rng(0))
    assert len(scan.faces) >= 300_000
    copy = T.republish([scan], method="isotropic", target_faces=60_000, texture_px=2048,
                       rotation=L.rotation_xyz((0.0, 90.0, 120.0)), scale=0.01, seed=5)
    write(tmp_path / "lib", "scan", [scan])
    write(tmp_path / "lib", "scan_remeshed", copy)
    summary = ingest_paths(catalog, [tmp_path / "lib"], config=quick_config("ingest.workers=2"))
    assert summary.broken == 0, summary.broken_objects
    config = quick_config()
    with catalog.session() as s:
        items = [Item(o) for o in s.scalars(select(CatalogObject).order_by(CatalogObject.id))]
        t0 = time.perf_counter()
        F._describe(catalog, s, items, F.FilterSummary(), InThisProcess())  # in this process, as workers = 1
        t1 = time.perf_counter()
        found = pair_flags(items, config.filter)
        t2 = time.perf_counter()
    assert [f.kind for f in found] == ["near_duplicate_appearance"], [(f.kind, f.reason) for f in found]
    assert "same surface colours and layout from every side" in found[0].reason
    faces = [it.shape.faces for it in items if it.shape is not None]
    with capsys.disabled():
        print(f"\ncapture pair {faces} faces: descriptors {t1 - t0:.1f} s (both, cold), comparison {t2 - t1:.3f} s,"
              f" time per pair {t2 - t0:.1f} s; {found[0].reason}")
