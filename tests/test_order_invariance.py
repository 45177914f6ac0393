"""The catalog's order never changes a flag (issue 69): the shape alignment gives one figure whichever object
comes first, and the same library ingested forwards and in reverse (the ids reversed) gets the same flags,
the same statuses and the same review queue from `catalog filter`.

Before, the alignment mapped the second object of a pair (the catalog's order) onto the first: on 1,628
pairs of five catalogs the two directions differed by 0.032 at the 95th percentile and 262 fell on two
sides of a threshold (docs/curation.md, "Copies by shape")."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
from cross_source_library import objects
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.config import load_config
from mixcount.curation.finding import shape_match as S
from mixcount.curation.finding.catalog_filter import run_filter
from mixcount.demo import library as L
from mixcount.demo.traps import remesh

SAMPLES = Path(__import__("pymeshlab").__file__).parent / "tests" / "sample_meshes"
# a lean slice of tests/cross_source_library.py: the bunny and the cow with their copies from another source
# (decimated, flattened, turned, other units, re-baked or recoloured), two plain scans and three shape families
SLICE = ("bunny", "bunny_dec_flat_mm", "bunny_dec_flat_cm_dark", "bunny_dec_flat_recoloured", "cow_yellow",
         "cow_yellow_dec_flat_cm", "cow_olive_dec_flat", "cow_red_turned_mm", "airplane_grey", "mug0", "mug1", "mug2",
         "figurine0", "can0")


def _normalised_scans() -> dict[str, S.Normalised]:
    """Two real scans pymeshlab ships and a decimated, squashed, turned copy of each in cm."""
    rng = np.random.default_rng(69)
    out = {}
    for name in ("bunny10k_textured.obj", "cow.obj"):
        mesh = trimesh.load(SAMPLES / name, force="mesh", process=False)
        key = name.split(".")[0].replace("10k_textured", "")
        out[key] = S.normalise(trimesh.sample.sample_surface(mesh, 6000, seed=1)[0])
        turn = np.linalg.qr(rng.normal(size=(3, 3)))[0] @ np.diag([1.0, 0.8, 1.0])
        v, f = remesh(np.asarray(mesh.vertices) @ turn.T * 100.0, np.asarray(mesh.faces), method="decimate",
                      target_faces=800)
        out[key + "_copy"] = S.normalise(trimesh.sample.sample_surface(trimesh.Trimesh(v, f), 6000, seed=2)[0])
    return out


def test_alignment_is_the_same_whichever_object_comes_first():
    n = _normalised_scans()
    one_way, got = [], {}
    for a, b in [("bunny", "bunny_copy"), ("cow", "cow_copy"), ("bunny", "cow")]:
        ab = S.match(n[a], n[b], max_squash=1.34)
        ba = S.match(n[b], n[a], max_squash=1.34)
        assert ab.distance == ba.distance, (a, b)
        # the maps are each other's inverse (b onto a, a onto b)
        assert np.allclose((ab.rotation * ab.scale) @ (ba.rotation * ba.scale), np.eye(3), atol=1e-9)
        assert ab.stretch == pytest.approx(ba.stretch)
        # the other direction, which the order-free match never takes for this pair
        first, second = (n[a], n[b]) if n[a].digest > n[b].digest else (n[b], n[a])
        other = S._match(first, second, max_squash=1.34, quantile=S.QUANTILE, whole=S.WHOLE_STARTS).distance
        one_way.append(abs(other - ab.distance))
        # the search runs one way; its map polished the other way round can only lower the figure
        searched = S._match(second, first, max_squash=1.34, quantile=S.QUANTILE, whole=S.WHOLE_STARTS).distance
        assert ab.distance <= searched, (a, b)
        got[a, b] = ab
    # what the order-free match takes away: aligning one way or the other gives other figures
    assert max(one_way) > 1e-3, one_way
    # the copies stay copies (squashed 20 %: the map's stretch says so), far nearer than the two scans
    for key in ("bunny", "cow"):
        assert got[key, key + "_copy"].distance < 0.5 * got["bunny", "cow"].distance
        assert got[key, key + "_copy"].stretch > 1.1


def _write(root: Path) -> list[Path]:
    parts = objects()
    folders = []
    for name in SLICE:
        (root / name).mkdir(parents=True)
        (root / name / "model.glb").write_bytes(L.export_glb(parts[name]))
        folders.append(root / name)
    return folders


def _filtered(db: Path, data: Path, folders: list[Path]) -> tuple[dict, dict, dict]:
    """Ingest ``folders`` in this order into a fresh catalog and filter it: flags by folder name (ids taken out
    of the reasons), statuses, the review queue and every pair figure the filter computed (each catalog
    computes them afresh: the pair cache is taken away after each run; the per-object descriptors, keyed by
    content, are shared)."""
    config = load_config([], ["ingest.workers=2"])
    catalog = open_catalog(f"sqlite:///{db}", data_dir=str(data))
    try:
        assert ingest_paths(catalog, folders, config=config).new == len(folders)
        summary = run_filter(catalog, config, ground_truth=False)
        with catalog.session() as s:
            objs = {o.id: o for o in s.scalars(select(CatalogObject))}
            folder = {i: Path(o.model_path).parent.name for i, o in objs.items()}
            first = folder[min(objs)]
            flags = sorted((folder[f.object_id], f.kind, folder.get(f.pair_object_id or 0, ""), round(f.score, 6),
                            re.sub(r"#\d+ ", "#", f.reason or "")) for f in s.scalars(select(Flag)))
            status = {folder[i]: o.status for i, o in objs.items()}
        cache = {}
        for path in (data / "descriptors").glob("layouts_*.json"):
            cache.update(json.loads(path.read_text()))
            path.unlink()
    finally:
        catalog.close()
    queue = {"objects": summary.to_decide_objects, "pairs": summary.to_decide_pairs,
             "decide": sorted((f[0], f[2]) for f in flags if f[2] and f[1] not in ("look_alike",)),
             "candidates": summary.candidate_pairs}
    return {"flags": flags, "status": status, "first": first}, queue, cache


@pytest.mark.slow
def test_the_same_library_in_reverse_order_gets_the_same_flags(tmp_path: Path):
    folders = _write(tmp_path / "lib")
    forwards, queue_f, cache_f = _filtered(tmp_path / "forwards.db", tmp_path / "data", folders)
    backwards, queue_b, cache_b = _filtered(tmp_path / "backwards.db", tmp_path / "data", folders[::-1])
    assert (forwards["first"], backwards["first"]) == (SLICE[0], SLICE[-1])  # the ids are reversed
    pairs = {frozenset((f[0], f[2])) for f in forwards["flags"] if f[2]}
    print(f"\nforwards / reverse: {len(forwards['flags'])} / {len(backwards['flags'])} flags, {len(pairs)} pairs, "
          f"to decide {queue_f['objects']} / {queue_b['objects']} objects and {queue_f['pairs']} / {queue_b['pairs']} pairs, "
          f"{sum(k.startswith('shape-') for k in cache_f)} alignments")
    assert len(pairs) >= 5 and queue_f["pairs"] >= 2  # copies and look-alikes were flagged: the rules ran
    assert forwards["flags"] == backwards["flags"]
    assert forwards["status"] == backwards["status"]
    assert queue_f == queue_b
    # every pair figure computed afresh in each catalog is the same, under the same key
    assert cache_f == cache_b and any(k.startswith(f"shape-{S.MATCH_VERSION}") for k in cache_f)
