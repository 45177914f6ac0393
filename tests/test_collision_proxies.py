"""Collision proxies: the bounded convex hull (pure), its place in the catalog (alembic-migrated SQLite,
re-ingest of an old catalog), in the USD asset (guide prim with UsdPhysics collision) and in Blender's
settling: the same seeds settled through the proxies and through the full meshes' hulls, compared.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pytest

from tests.conftest import PROJECT_ROOT


def test_convex_proxy_bounds_vertices_and_reports_its_gap() -> None:
    import trimesh

    from mixcount.catalog.proxies import convex_proxy

    sphere = trimesh.creation.icosphere(subdivisions=5)  # 10242 vertices, all on the hull
    for budget in (16, 64, 128):
        p = convex_proxy(sphere.vertices, budget)
        mesh = trimesh.Trimesh(p.vertices, p.faces, process=False)
        assert 4 <= len(p.vertices) <= budget
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0  # outward, closed
        # an inner approximation: every proxy vertex is an input vertex, the gap is what it reports
        assert np.abs(np.linalg.norm(p.vertices, axis=1) - 1.0).max() < 1e-9
        assert 0 < p.error_m < (0.35 if budget == 16 else 0.1)
    fine, coarse = convex_proxy(sphere.vertices, 128), convex_proxy(sphere.vertices, 16)
    assert fine.error_m < coarse.error_m
    box = trimesh.creation.box((0.3, 0.1, 0.002))  # a flat object stays a (thin) hull, exactly
    p = convex_proxy(np.vstack([box.vertices, box.sample(500, seed=1)]), 64)
    assert len(p.vertices) == 8 and p.error_m < 1e-9


def test_ingest_stores_proxy_and_reingest_fills_an_old_catalog(tmp_path: Path, catalog) -> None:
    from sqlalchemy import select

    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject
    from mixcount.catalog.proxies import read_proxy
    from mixcount.config import load_config
    from mixcount.demo.library import generate_demo_library

    generate_demo_library(tmp_path / "lib", seed=0, n_objects=3)
    cfg = load_config([], ["ingest.proxy_max_vertices=48", "ingest.workers=1"])
    cat = catalog
    ingest_paths(cat, [tmp_path / "lib"], config=cfg)
    with cat.session() as s:
        objs = [o for o in s.scalars(select(CatalogObject)) if o.status != "broken"]
        assert objs
        for o in objs:
            verts, faces = read_proxy(Path(o.proxy_path))
            assert o.proxy_vertex_count == len(verts) <= 48 and len(faces) >= 4
            # the proxy sits in the collision mesh's frame: same bounding box within its gap
            coll = read_proxy(Path(o.collision_path))[0]
            assert np.allclose(verts.max(0), coll.max(0), atol=0.05 * max(o.dims))
        ids = {o.id for o in objs}
        for o in objs:  # a catalog from before proxies: no proxy recorded
            o.proxy_path, o.proxy_vertex_count = None, None
        s.commit()
    summary = ingest_paths(cat, [tmp_path / "lib"], config=load_config([], ["ingest.proxy_max_vertices=32", "ingest.workers=1"]))
    assert summary.new == 0
    with cat.session() as s:
        objs = [o for o in s.scalars(select(CatalogObject)) if o.status != "broken"]
        assert {o.id for o in objs} == ids  # filled in place, no duplicates
        assert all(o.proxy_path.endswith("_hull32.ply") and o.proxy_vertex_count <= 32 for o in objs)


@pytest.fixture(scope="module")
def full_demo_library(demo_library: tuple[Path, dict]) -> tuple[Path, dict]:
    """The whole demo library (its scans are OBJ files in centimetres, Y-up) and its ground truth: the
    session's seed-0 library (tests/conftest.py), read only here."""
    return demo_library


def test_ingested_scan_in_centimetres_gets_a_proxy_of_its_true_size(tmp_path: Path, catalog,
                                                                      full_demo_library) -> None:
    """The product path for a scan (OBJ in cm, Y-up, plain folder): ingest stores a proxy whose box is the
    object's true size in metres, Z-up, and the asset converts with it (the converter's fit check)."""
    from sqlalchemy import select

    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.models import CatalogObject
    from mixcount.catalog.proxies import read_proxy
    from mixcount.config import load_config
    from mixcount.usd.assets import convert_asset

    root, truth = full_demo_library
    scans = {o["folder"]: o for o in truth["objects"] if o.get("units") == "cm"}
    assert scans, "the demo library must hold a scan in centimetres"
    ingest_paths(catalog, [root / folder for folder in scans],
                 config=load_config([], ["ingest.workers=1"]))
    with catalog.session() as s:
        objs = [o for o in s.scalars(select(CatalogObject)) if o.status != "broken"]
        assert len(objs) == len(scans)
        for o in objs:
            true_dims = next(t["dims_m"] for f, t in scans.items() if f in o.model_path)
            verts, _ = read_proxy(Path(o.proxy_path))
            assert np.allclose(verts.max(0) - verts.min(0), true_dims, rtol=0.03, atol=1e-3), o.model_path
            paths = convert_asset(o.model_path, tmp_path / "assets", content_hash=o.content_hash or "",
                                  units=o.source_units, up_axis=o.source_up_axis, proxy_path=o.proxy_path)
            assert paths.has_proxy


def test_pool_proxies_fit_their_objects_whatever_the_source_units(tmp_path: Path, full_demo_library) -> None:
    """A scan's OBJ in centimetres, Y-up gets its proxy in metres, Z-up like its render mesh. It used to be
    built from the file read as metres: a body 100x the object, which flung a whole bowl scene apart
    (bodies hundreds of km away). The USD converter now refuses a proxy that does not fit its model."""
    from mixcount.catalog.proxies import build_proxy, read_proxy
    from mixcount.demo.demo_pools import pool_from_demo_library
    from mixcount.errors import CompositionError
    from mixcount.usd.assets import convert_asset

    pool = pool_from_demo_library(full_demo_library[0], proxy_dir=tmp_path / "proxies")
    scans = [r for r in pool if r.source_units == "cm"]
    assert scans, "the demo library must hold a scan in centimetres"
    for rec in pool:
        verts, _ = read_proxy(Path(rec.proxy_path))
        extent = verts.max(axis=0) - verts.min(axis=0)  # the axis extremes seed the proxy: the full box
        assert np.allclose(extent, rec.dims, rtol=0.01, atol=1e-4), (rec.name, extent, rec.dims)
    scan = scans[0]
    ok = convert_asset(scan.model_path, tmp_path / "assets", content_hash=scan.content_hash, units="cm",
                       up_axis=scan.source_up_axis, proxy_path=scan.proxy_path)
    assert ok.has_proxy
    wrong = tmp_path / "wrong_hull64.ply"  # the old mistake: the same points in centimetres
    build_proxy(read_proxy(Path(scan.proxy_path))[0] * 100.0, wrong, 64)
    with pytest.raises(CompositionError, match="does not fit model"):
        convert_asset(scan.model_path, tmp_path / "assets2", content_hash=scan.content_hash, units="cm",
                      up_axis=scan.source_up_axis, proxy_path=str(wrong))


@pytest.fixture(scope="module")
def proxy_library(tmp_path_factory: pytest.TempPathFactory):
    from mixcount.demo.demo_pools import pool_from_demo_library
    from mixcount.demo.library import generate_demo_library

    root = tmp_path_factory.mktemp("plib")
    generate_demo_library(root / "demo", seed=0, n_objects=8)
    return pool_from_demo_library(root / "demo", proxy_dir=root / "proxies", proxy_max_vertices=64), root


def _spec(pool, seed: int, proxies: bool, *overrides: str):
    from mixcount.config import load_config
    from mixcount.scene.sampler import sample_scene

    cfg = load_config([PROJECT_ROOT / "configs" / "quick.toml"],
                      ["scene.n_objects=[16,16]", "scene.physics_frames=200", f"scene.collision_proxies={str(proxies).lower()}",
                       "compose.resolution=64", "compose.samples=1", *overrides])
    return sample_scene(seed, "train", cfg, pool)


def test_usd_asset_holds_guide_proxy_with_collision(proxy_library, tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom, UsdPhysics

    from mixcount.usd.stage import write_stage

    pool, root = proxy_library
    for proxies in (True, False):
        spec = _spec(pool, 5, proxies)
        stage_path = write_stage(spec, tmp_path, assets_dir=root / "assets", scene_dir=tmp_path / str(proxies))
        stage = Usd.Stage.Open(str(stage_path))
        prim = stage.GetPrimAtPath("/World/Objects/obj_0001")
        proxy = stage.GetPrimAtPath("/World/Objects/obj_0001/Proxy")
        assert proxy and proxy.IsA(UsdGeom.Mesh)
        assert UsdGeom.Imageable(proxy).ComputePurpose() == UsdGeom.Tokens.guide
        assert proxy.HasAPI(UsdPhysics.CollisionAPI) and proxy.HasAPI(UsdPhysics.MeshCollisionAPI)
        assert UsdPhysics.MeshCollisionAPI(proxy).GetApproximationAttr().Get() == "convexHull"
        assert len(UsdGeom.Mesh(proxy).GetPointsAttr().Get()) <= 64
        assert UsdPhysics.CollisionAPI(proxy).GetCollisionEnabledAttr().Get() is proxies
        assert prim.HasAPI(UsdPhysics.RigidBodyAPI)
        assert prim.HasAPI(UsdPhysics.CollisionAPI) is (not proxies)  # one collider per body


@pytest.fixture(scope="module")
def settled_scene(proxy_library, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[..., dict]]:
    """``settled_scene(seed, proxies, *overrides)``: the metadata.json of that scene (``_spec``), composed by
    one bpy worker for the module; a scene two tests ask for (seed 11 with proxies and the default floor)
    is rendered once. Each call returns a fresh parse: a test may change what it gets."""
    from mixcount.config import load_config
    from mixcount.run.scene_task import SceneTask, run_scene_task
    from mixcount.worker.client import BlenderWorker
    from mixcount.worker.contract import SceneOutputs

    pool, root = proxy_library
    work = tmp_path_factory.mktemp("settled")
    written: dict[tuple, Path] = {}
    with BlenderWorker(name="proxy-test", log_dir=work) as worker:
        def scene(seed: int, proxies: bool, *overrides: str) -> dict:
            key = (seed, proxies, *overrides)
            if key not in written:
                spec = _spec(pool, seed, proxies, *overrides)
                task = SceneTask(spec=spec, out_dir=str(work / f"out{len(written)}"), assets_dir=str(root / "assets"),
                                 timeout_s=600, threads=2, outputs=SceneOutputs.from_config(load_config().compose))
                outcome = run_scene_task(task, worker)
                assert outcome.status == "written", outcome.error
                written[key] = Path(outcome.path) / "metadata.json"
            return dict(json.loads(written[key].read_text()))

        yield scene


@pytest.mark.blender
@pytest.mark.slow
def test_settling_through_proxies_is_no_worse_on_the_same_seeds(settled_scene) -> None:
    """Same seeds, proxies on and off: no more settle drops, nothing sinks, nothing interpenetrates beyond
    the worker's checks, and bodies are at rest at the end."""
    from mixcount.scene_decisions import BELOW_FLOOR, FLUNG_OUT, INTERPENETRATION, UNSTABLE

    settle_reasons = {BELOW_FLOOR, FLUNG_OUT, UNSTABLE, INTERPENETRATION}
    results: dict[bool, list[dict]] = {True: [], False: []}
    for seed in (11, 12):
        for proxies in (False, True):
            results[proxies].append(settled_scene(seed, proxies))
            assert results[proxies][-1]["scene_id"] == f"scene_{seed:06d}"
    moving = {True: 0, False: 0}
    for proxies, metas in results.items():
        for meta in metas:
            rest = next(d for d in meta["diagnostics"] if d["kind"] == "rest")
            assert (rest["proxies"] > 0) is proxies
            kept = {o["name"]: o for o in meta["objects"] if o["status"] == "kept"}
            for o in kept.values():
                assert o["min_z"] >= -0.02 * o["size_m"], (proxies, o["name"], o["min_z"])  # no sinking
            # distractors are placed after physics on the floor (not simulated): speeds of counted bodies
            speeds = [rest["speed_m_s"][name] for name, o in kept.items() if o["role"] == "counted"]
            assert np.median(speeds) < 0.05, (proxies, speeds)  # the pile is at rest ...
            moving[proxies] += sum(v > 0.1 for v in speeds)  # ... but for a body still rolling here and there

    def drops(metas: list[dict]) -> int:
        return sum(1 for m in metas for o in m["objects"] if o.get("reason") in settle_reasons)

    assert drops(results[True]) <= drops(results[False]) + 1
    assert moving[True] <= moving[False] + 1
    assert all(m["physics"]["frames"] == 200 for m in results[True])


@pytest.mark.blender
@pytest.mark.slow
def test_deep_floor_collider_settles_as_well_as_the_thin_floor(proxy_library, settled_scene) -> None:
    """The default physics (8 substeps, floor colliding 0.5·s deep, containers through convex parts)
    against the bare 0.5 m floor, same seeds: no more settle drops, nothing sinking, a pile at rest."""
    from mixcount.scene_decisions import BELOW_FLOOR, FLUNG_OUT, INTERPENETRATION, UNSTABLE

    pool, _root = proxy_library
    settle_reasons = {BELOW_FLOOR, FLUNG_OUT, UNSTABLE, INTERPENETRATION}
    variants = {"default": (), "before": ("scene.physics_floor_collider_depth=0.0",)}
    drops = {name: 0 for name in variants}
    containers = 0
    for seed in (11, 13):
        for name, overrides in variants.items():
            spec = _spec(pool, seed, True, *overrides)
            assert (spec.physics.substeps, spec.physics.floor_collider_depth > 0) == (8, name == "default")
            meta = settled_scene(seed, True, *overrides)  # seed 11 "default": the scene the test above settled
            assert meta["scene_id"] == f"scene_{seed:06d}"
            kept = [o for o in meta["objects"] if o["status"] == "kept"]
            for o in kept:
                assert o["min_z"] >= -0.02 * o["size_m"], (name, o["name"], o["min_z"])  # no sinking
            rest = next(d for d in meta["diagnostics"] if d["kind"] == "rest")
            assert np.median([rest["speed_m_s"][o["name"]] for o in kept if o["role"] == "counted"]) < 0.05, name
            drops[name] += sum(1 for o in meta["objects"] if o.get("reason") in settle_reasons)
            if meta["spec"]["container"] is not None:  # it collides through its convex parts
                coll = [d for d in meta["diagnostics"] if d["kind"] == "container_collision"]
                assert len(coll) == 1 and coll[0]["source"] == "convex parts" and coll[0]["parts"] >= 2, coll
                containers += 1
    assert containers > 0, "the seeds must draw a container"
    assert drops["default"] <= drops["before"], drops
