"""The two public pairs of issue 49: the Stanford bunny and the rubber duck as pybullet (``pybullet_data``)
and genesis-world ship them (902 against 84,818 faces; 4,212 faces at 0.083 m against 3,534 faces at 354
units, other textures), read out of the wheels (``pip download --no-deps``; ``$MIXCOUNT_WHEELS`` names a
folder that holds them). Skips, saying why, when the wheels cannot be had.

Among the distinct objects of the capture-like pool (tests/copy_pool.py, whose textured Stanford bunny is
a third copy of the bunny), each in a plain colour of its own, the pair rules pair both public pairs (a
possible copy, a duplicate or a variant) and raise no pair of different objects for a decision.

Each public model has the appearance ingest reads in it (:func:`mixcount.catalog.mesh.load_normalised`): the
ducks are textured, both bunnies untextured. The bunnies agree only loosely (the pybullet one is a
902-face approximation: aligned distance 0.086 against 0.094 from the nearest primitive), and a loose
agreement needs agreeing colours beside it, which two untextured surfaces do not have (both are read in
one grey): the two public bunnies are a look-alike for a person, and the genesis bunny is paired with
the pool's textured bunny by its shape evidence. Counting two untextured surfaces' grey as agreement
raised, with every pool object in that grey, two pairs of different objects among five to decide (cup /
mug, the two lumpy scan stand-ins) and a drawer / mug pair of metaworld's untextured parts
(docs/curation.md)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from copy_pool import PUBLIC_PAIRS, originals, public_models

from mixcount.catalog.mesh import load_normalised
from mixcount.catalog.models import CatalogObject
from mixcount.config import load_config
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding.catalog_filter import candidate_items
from mixcount.curation.finding.copy_rules import pair_flags
from mixcount.curation.finding.filter_items import Item, LayoutCache
from mixcount.curation.flag_kinds import DUPLICATE_KINDS, LOOK_ALIKE, RELATION_KINDS, severity
from mixcount.sizes import metres_per_unit, plausible_unit

pytestmark = pytest.mark.slow
GREY: float | None = None  # one grey for every pool object instead of a plain colour each (the worst case)


def test_public_pairs_paired_and_nothing_else(tmp_path):
    models, why = public_models(tmp_path / "public")
    if models is None:
        pytest.skip(why)
    items, name = [], {}
    for oid, (label, path) in enumerate(sorted(models.items()), start=1):
        mesh = trimesh.load(path, force="mesh")
        points, colours = A.surface_samples(path)
        obj = CatalogObject(id=oid, name=label, content_hash=f"{oid:032x}", geometry_hash=f"g{oid:031x}")
        v = np.asarray(mesh.vertices, float)
        unit = plausible_unit(float(np.ptp(v, axis=0).max()), "m")  # real sizes as ingest reads them (issue 57)
        shape = D.shape_descriptor(v * (metres_per_unit(unit) if unit else 1.0), np.asarray(mesh.faces),
                                   watertight=False, volume=None, quality=False)
        items.append(Item(obj, shape=shape, surface=A.surface_look(points, colours),
                          appearance=load_normalised(path).appearance))
        name[oid] = label
    palette = np.random.default_rng(7)
    for oid, (label, (v, f)) in enumerate(sorted(originals().items()), start=100):
        points = D.sample_surface(v, f, A.N_SAMPLES, np.random.default_rng(oid))
        colour = palette.uniform(0.05, 0.95, 3) if GREY is None else np.full(3, GREY)
        obj = CatalogObject(id=oid, name=label, content_hash=f"{oid:032x}", geometry_hash=f"g{oid:031x}")
        shape = D.shape_descriptor(v, f, watertight=False, volume=None, quality=False)
        items.append(Item(obj, shape=shape, surface=A.surface_look(points, np.tile(colour, (len(points), 1))),
                          appearance="material"))
        name[oid] = label
    th = load_config().filter
    found = pair_flags(items, th, LayoutCache(None), candidate_items(items, th.candidates))
    decide = {frozenset((name[f.a], name[f.b])): f for f in found
              if f.b is not None and severity(f.kind, f.reason) == "decide"}
    assert {name[it.obj.id]: it.appearance for it in items if it.obj.id < 100} == {
        "bunny_genesis": "none", "bunny_pybullet": "none", "duck_genesis": "image", "duck_pybullet": "image"}
    decided = [("duck_pybullet", "duck_genesis"), ("bunny_genesis", "bunny")]
    for pair in decided:
        f = decide.get(frozenset(pair))
        assert f is not None and f.kind in DUPLICATE_KINDS + RELATION_KINDS, (pair, sorted(map(sorted, decide)))
        print(f"\n{pair}: {f.kind} {f.score:.2f}: {f.reason}")
    untextured = [f for f in found if {name[f.a], name.get(f.b)} == {"bunny_pybullet", "bunny_genesis"}]
    assert [f.kind for f in untextured] == [LOOK_ALIKE] and "untextured" in untextured[0].reason, untextured
    flagged = {frozenset((name[f.a], name[f.b])) for f in found if f.b is not None}
    assert all(frozenset(pair) in flagged for pair in PUBLIC_PAIRS), sorted(map(sorted, flagged))
    same = {"bunny": "bunny", "bunny_pybullet": "bunny", "bunny_genesis": "bunny", "duck_pybullet": "duck",
            "duck_genesis": "duck"}
    false = sorted(sorted(p) for p in decide if len({same.get(n, n) for n in p}) > 1)
    print(f"decide pairs {len(decide)}, between different objects {len(false)}: {false}")
    assert false == [], false
