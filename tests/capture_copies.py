"""Copies of real captures as other sources make them (issue 57), for tests/test_capture_copies.py and
bench/curation_copies.py: models from five public packages, each copied six ways, each way on its own.

Originals (real files; textured where the package ships a texture), in two parts:

* :data:`TUNING` (looked at while the rules were set): pybullet's duck (texture), genesis-world's dragon
  and worm (textures), metaworld's mug (untextured STL), glmark2-data's Stanford bunny (untextured);
* :data:`HELD_OUT` (not looked at while tuning, reported apart): assimp-testmodels' spider (OBJ) and
  Wuson (STL), genesis-world's boat (16 textures) and airplane, metaworld's thermos body and hammer head,
  prusa-slicer's Stanford bunny (STL), pybullet's lego brick.

Copies (:data:`KINDS`), each of one kind only but the last, seeded by the original's name:

* ``print``: another print: the colours turned in hue (a texture) or another plain colour (untextured);
* ``resolution``: quadric decimation to 10-20 % of the faces, the texture baked to vertex colours (odd
  originals) or flattened to its mean colour (even ones);
* ``squash``: one random model axis scaled by 0.75-0.9;
* ``units``: the numbers converted into another unit (mm, inches, cm or m; read back as ingest reads them);
* ``pose``: a random rotation and offset;
* ``reindex``: the same topology re-indexed (vertices and faces permuted) and sampled afresh;
* ``compound``: several changes at once, as a second source makes them (issue 69): other units, a squash and
  another pose, with another resolution (odd seeds) or another print (even ones).

Look-alikes (:data:`LOOK_ALIKES`): distinct objects of one kind that must stay apart: metaworld's mug and
cup, pybullet's mug, genesis-world's bolt and nut, and demo mugs, bowls and bottles of other proportions.

Each entry is (name, group, part, points, colours, shape descriptor); objects of one group are one object.
:func:`pool` returns (entries, "") or (None, why) when a package cannot be had."""

from __future__ import annotations

import zlib
from pathlib import Path
from typing import Any, Optional

import numpy as np
import public_packages as P
import trimesh
from scipy.spatial import cKDTree

from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import descriptors as D
from mixcount.sizes import metres_per_unit, plausible_unit

G, MW = P.GENESIS_MESHES, P.METAWORLD_MESHES
TUNING: dict[str, tuple[str, str]] = {
    "duck_pybullet": (P.PYBULLET, "pybullet_data/duck.obj"),
    "dragon_genesis": (P.GENESIS, f"{G}/dragon/dragon.obj"),
    "worm_genesis": (P.GENESIS, f"{G}/worm/worm.obj"),
    "mug_metaworld": (P.METAWORLD, f"{MW}/coffeemachine/mug.stl"),
    "bunny_glmark2": (P.GLMARK2, "usr/share/glmark2/models/bunny.obj"),
}
HELD_OUT: dict[str, tuple[str, str]] = {
    "spider_assimp": (P.ASSIMP, "usr/share/assimp/models/OBJ/spider.obj"),
    "wuson_assimp": (P.ASSIMP, "usr/share/assimp/models/STL/Wuson.stl"),
    "boat_genesis": (P.GENESIS, f"{G}/boat/boat.obj"),
    "airplane_genesis": (P.GENESIS, f"{G}/Airplane/airplane.obj"),
    "thermos_metaworld": (P.METAWORLD, f"{MW}/thermos/therm_body.stl"),
    "hammer_metaworld": (P.METAWORLD, f"{MW}/hammer/hammerhead.stl"),
    "bunny_prusa": (P.PRUSA, "usr/share/PrusaSlicer/shapes/bunny.stl"),
    "lego_pybullet": (P.PYBULLET, "pybullet_data/lego/lego.obj"),
}
LOOK_ALIKE_FILES: dict[str, tuple[str, str]] = {
    "cup_metaworld": (P.METAWORLD, f"{MW}/coffeemachine/cup.stl"),
    "mug_pybullet": (P.PYBULLET, "pybullet_data/objects/mug.obj"),
    "bolt_genesis": (P.GENESIS, f"{G}/bolt_nut/bolt.stl"),
    "nut_genesis": (P.GENESIS, f"{G}/bolt_nut/nut.stl"),
}
DEMO_LOOK_ALIKES = (("mug", 1), ("mug", 2), ("bowl", 1), ("bowl", 2), ("bottle", 1), ("bottle", 2))
KINDS = ("print", "resolution", "squash", "units", "pose", "reindex", "compound")
SINGLE_KINDS = KINDS[:-1]
UNITS = ("mm", "in", "cm", "m")
Entry = tuple[str, str, str, np.ndarray, np.ndarray, Any]


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _metres(extent: float) -> float:
    """Metres per file unit as ingest would read the file: metres, re-read where implausible."""
    unit = plausible_unit(extent, "m")
    return metres_per_unit(unit) if unit else 1.0


def _entry(name: str, group: str, part: str, v: np.ndarray, f: np.ndarray, points: np.ndarray,
           colours: np.ndarray, scale: float) -> Entry:
    shape = D.shape_descriptor(v * scale, f, watertight=False, volume=None, quality=False)
    return name, group, part, points, np.clip(colours, 0.0, 1.0), shape


def _hue_turn(colours: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Another print: colours turned about the grey axis by 90-150 degrees (a plain grey becomes a plain
    colour: the grey is first tinted)."""
    c = np.asarray(colours, float)
    if np.abs(c - c.mean(axis=0)).sum(axis=1).mean() < 0.05:  # plain: another plain colour
        return np.tile(rng.choice([(0.8, 0.2, 0.2), (0.2, 0.5, 0.8), (0.9, 0.8, 0.2)]), (len(c), 1)).astype(float)
    angle = np.radians(rng.uniform(90.0, 150.0))
    axis = np.ones(3) / np.sqrt(3.0)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    mean = c.mean(axis=0)
    return (c - mean) @ rot.T + mean


def copies(name: str, part: str, v: np.ndarray, f: np.ndarray, dense: tuple[np.ndarray, np.ndarray],
           scale: float, seed: int) -> list[Entry]:
    """The copies of one original (see the module doc), one per kind of :data:`KINDS`."""
    out = []
    tree = cKDTree(dense[0])
    for k, kind in enumerate(KINDS):
        rng = np.random.default_rng(seed * 10 + k)
        changes = {kind}
        if kind == "compound":
            changes = {"units", "squash", "pose", "resolution" if seed % 2 else "print"}
        cv, cf = v.copy(), f.copy()
        if "resolution" in changes:
            from mixcount.demo.traps import remesh

            cv, cf = remesh(cv, cf, method="decimate", target_faces=max(int(len(f) * rng.uniform(0.1, 0.2)), 60))
        if "reindex" in changes:
            perm = rng.permutation(len(cv))
            inverse = np.empty_like(perm)
            inverse[perm] = np.arange(len(perm))
            cv, cf = cv[perm], inverse[cf][rng.permutation(len(cf))]
        points = D.sample_surface(cv, cf, A.N_SAMPLES, rng)
        colours = dense[1][tree.query(points)[1]]
        if "print" in changes:
            colours = _hue_turn(colours, rng)
        if "resolution" in changes:
            if seed % 2:  # baked to vertex colours: each sample takes its nearest vertex's colour
                vertex_colour = dense[1][tree.query(cv)[1]]
                colours = vertex_colour[cKDTree(cv).query(points)[1]]
            else:  # flattened to one colour
                colours = np.tile(colours.mean(axis=0), (len(colours), 1))
        turn, factor, shift = np.eye(3), np.ones(3), np.zeros(3)
        if "squash" in changes:
            factor[rng.integers(0, 3)] = rng.uniform(0.75, 0.9)
        if "pose" in changes:
            turn, shift = _rotation(rng), rng.normal(size=3) * float(np.ptp(v, axis=0).max())
        unit = 1.0
        if "units" in changes:  # the numbers converted from the original's unit into another one
            others = [u for u in UNITS if abs(metres_per_unit(u) - scale) > 1e-12]
            unit = scale / metres_per_unit(others[seed % len(others)])

        def moved(p: np.ndarray, turn: np.ndarray = turn, factor: np.ndarray = factor, shift: np.ndarray = shift,
                  unit: float = unit) -> np.ndarray:
            return ((p * factor) @ turn.T + shift) * unit

        cscale = _metres(float(np.ptp(moved(cv), axis=0).max()))
        out.append(_entry(f"{name}_{kind}", name, part, moved(cv), cf, moved(points), colours, cscale))
    return out


def _load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    scene = trimesh.load(str(path), force="scene", process=False)
    mesh = scene.to_geometry() if hasattr(scene, "to_geometry") else scene.dump(concatenate=True)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces)


def pool(parts: tuple[str, ...] = ("tuning", "held_out"), only: Optional[set[str]] = None,
         demo_look_alikes: bool = True) -> tuple[Optional[list[Entry]], str]:
    """Every original of ``parts`` with its copies, and the look-alikes (see the module doc); ``only``: these
    originals and look-alikes (by name) and no others."""
    from mixcount.demo import objects as O
    from mixcount.demo import traps as T

    chosen = {"tuning": TUNING, "held_out": HELD_OUT}
    entries: list[Entry] = []
    for part in parts:
        for name, (package, rel) in chosen[part].items():
            if only is not None and name not in only:
                continue
            root, why = P.package_root(package)
            if root is None:
                return None, why
            path = root / rel
            v, f = _load(path)
            points, colours = A.surface_samples(path)
            dense = A.surface_samples(path, n=40000, seed=7)
            scale = _metres(float(np.ptp(v, axis=0).max()))
            entries.append(_entry(name, name, part, v, f, points, colours, scale))
            entries.extend(copies(name, part, v, f, dense, scale, zlib.crc32(name.encode()) % 1000))
    for name, (package, rel) in LOOK_ALIKE_FILES.items():
        if only is not None and name not in only:
            continue
        root, why = P.package_root(package)
        if root is None:
            return None, why
        v, f = _load(root / rel)
        points, colours = A.surface_samples(root / rel)
        entries.append(_entry(name, name, "look_alike", v, f, points, colours, _metres(float(np.ptp(v, axis=0).max()))))
    builders = {"mug": O.build_mug, "bowl": O.build_bowl, "bottle": O.build_bottle}
    for family, k in DEMO_LOOK_ALIKES if demo_look_alikes else ():
        v, f = T.weld(builders[family](k, np.random.default_rng(100 + k)).parts)
        points = D.sample_surface(v, f, A.N_SAMPLES, np.random.default_rng(k))
        entries.append(_entry(f"{family}{k}_demo", f"{family}{k}_demo", "look_alike", v, f, points,
                              np.full((len(points), 3), 0.7), 1.0))
    return entries, ""


def items_of(entries: list[Entry]) -> list[Any]:
    """The filter's view of each entry (:class:`mixcount.curation.finding.filter_items.Item`), ids from 1."""
    from mixcount.catalog.models import CatalogObject
    from mixcount.curation.finding.filter_items import Item

    out = []
    for oid, (name, _group, _part, points, colours, shape) in enumerate(entries, start=1):
        obj = CatalogObject(id=oid, name=name, content_hash=f"{oid:032x}", geometry_hash=f"g{oid:031x}")
        plain = float(np.abs(colours - colours.mean(axis=0)).sum(axis=1).mean()) < 0.05
        out.append(Item(obj, shape=shape, surface=A.surface_look(points, colours),
                        appearance="material" if plain else "image"))
    return out


def evaluate(entries: list[Entry], th: Any) -> dict[str, Any]:
    """Run the pair rules as `catalog filter` runs them (candidates from the index, then the rules) and
    count: per part and kind, the copies among the candidates and the copies paired (a *decide* pairing:
    a duplicate kind, colour_variant or possible_copy); the decide pairs between different objects, the
    duplicates (which exclude) between different objects, and the look-alike pairs (info)."""
    from mixcount.curation.finding.catalog_filter import candidate_items
    from mixcount.curation.finding.copy_rules import pair_flags
    from mixcount.curation.finding.filter_items import LayoutCache
    from mixcount.curation.flag_kinds import DUPLICATE_KINDS, severity

    items = items_of(entries)
    group = {i: e[1] for i, e in enumerate(entries, start=1)}
    name = {i: e[0] for i, e in enumerate(entries, start=1)}
    part = {i: e[2] for i, e in enumerate(entries, start=1)}
    compare = candidate_items(items, th.candidates)
    candidates = {frozenset((x.obj.id, y.obj.id)) for x, y in compare}
    found = pair_flags(items, th, LayoutCache(None), compare)
    decide: dict[frozenset[int], set[str]] = {}
    duplicates: set[frozenset[int]] = set()
    for f in found:
        if f.b is None:
            continue
        key = frozenset((f.a, f.b))
        if severity(f.kind, f.reason) == "decide":
            decide.setdefault(key, set()).add(f.kind)
        if f.kind in DUPLICATE_KINDS:
            duplicates.add(key)
    originals = {i for i in name if name[i] == group[i]}
    per: dict[str, dict[str, list[int]]] = {}
    missed = []
    for i in name:
        if i in originals or part[i] == "look_alike":
            continue
        orig = next(o for o in originals if group[o] == group[i])
        kind = name[i][len(group[i]) + 1:]
        key = frozenset((i, orig))
        row = per.setdefault(part[i], {}).setdefault(kind, [0, 0, 0])
        row[0] += 1
        row[1] += key in candidates
        row[2] += key in decide
        if key not in decide:
            missed.append(name[i])
    false = sorted(" / ".join(sorted(name[i] for i in p)) for p in decide if len({group[i] for i in p}) > 1)
    true_pairs = sum(1 for p in decide if len({group[i] for i in p}) == 1)
    return {
        "objects": len(items), "candidate_pairs": len(compare),
        "per_kind": {p: {k: {"copies": r[0], "candidates": r[1], "paired": r[2]} for k, r in kinds.items()}
                     for p, kinds in per.items()},
        "missed": sorted(missed), "decide_pairs": len(decide), "decide_same_object": true_pairs,
        "precision": round(true_pairs / max(1, len(decide)), 4), "false_pairs": false,
        "false_duplicates": sorted(" / ".join(sorted(name[i] for i in p)) for p in duplicates
                                   if len({group[i] for i in p}) > 1),
    }
