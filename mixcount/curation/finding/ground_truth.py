"""Precision and recall of `catalog filter` against a demo library's ``ground_truth.json``."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable

from sqlalchemy import select

from mixcount.catalog.db import Catalog
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.curation.flag_kinds import (
    COLOUR_VARIANT,
    DEGENERATE,
    DUPLICATE_KINDS,
    MESH_QUALITY,
    POSSIBLE_COPY,
    QUALITY_KINDS,
    RELATION_KINDS,
)


def find_ground_truth(objects: Iterable[CatalogObject]) -> Path | None:
    """``ground_truth.json`` of the demo library the objects were ingested from (next to their folders)."""
    roots: dict[Path, int] = defaultdict(int)
    for o in objects:
        if o.model_path:
            roots[Path(o.model_path).parent.parent] += 1
    for root, _ in sorted(roots.items(), key=lambda kv: -kv[1]):
        gt = root / "ground_truth.json"
        if gt.is_file():
            return gt
    return None


VARIANT_TRAPS = ("recolour",)  # trap kinds that are colour variants (a class pair), not duplicates
TRAP_KINDS = (  # ground_truth.json key -> trap kind
    ("exact_copies", "exact"), ("recolours", "recolour"), ("rescales", "rescale"),
    ("turned_rescales", "turned_rescale"), ("retessellated", "retessellated"), ("other_source", "other_source"),
    ("remeshed", "remeshed"), ("unit_changes", "units"), ("rebaked", "rebaked"), ("split_parts", "split"),
)


def evaluate_against_ground_truth(catalog: Catalog, path: Path | None = None) -> dict[str, Any] | None:
    """Precision/recall of duplicate pairs, per trap kind, against a demo library's ground truth.

    Objects are matched by their folder name. A predicted pair (any duplicate kind, ``colour_variant`` or
    ``possible_copy``) is correct when both objects belong to one planted group (two copies of one
    original are duplicates of each other too). Per trap kind: recall = planted pairs found with the
    expected kind (``colour_variant`` for the recolours of :data:`VARIANT_TRAPS`, a duplicate kind for the
    others); precision = of the predicted pairs that involve the kind's copies, the share that is correct.
    ``clean`` objects are those in no planted group and not broken; the share of them carrying any
    duplicate flag is the false-flag rate (at most 5 % by the issue's bound), ``clean_paired`` counts
    those with any pairing (variants and possible copies too).
    Also: broken files flagged degenerate, and each planted ``mesh_quality`` object's flags and status.
    """
    with catalog.session() as session:
        objects = session.scalars(select(CatalogObject)).all()
        gt_path = path or find_ground_truth(objects)
        if gt_path is None:
            return None
        try:
            truth = json.loads(Path(gt_path).read_text())
        except (OSError, ValueError):
            return None
        root = Path(gt_path).parent.resolve()
        folder_of: dict[int, str] = {}
        status_of: dict[str, str] = {}
        for o in objects:
            p = Path(o.model_path).parent
            if p.parent.resolve() == root:
                folder_of[o.id] = p.name
                status_of[p.name] = o.status
        id_of = {v: k for k, v in folder_of.items()}
        flags = session.scalars(select(Flag).where(Flag.object_id.in_(list(folder_of)))).all()
    true_pairs: dict[frozenset[str], str] = {}
    copy_kind: dict[str, str] = {}
    for key, kind in TRAP_KINDS:
        for entry in truth.get(key, []):
            if entry[0] in id_of and entry[1] in id_of:
                true_pairs[frozenset(entry[:2])] = kind
                copy_kind[entry[1]] = kind
    group_of: dict[str, int] = {}
    for k, group in enumerate(connected_groups(tuple(p) for p in true_pairs)):
        for name in group:
            group_of[name] = k
    predicted: dict[frozenset[str], set[str]] = defaultdict(set)
    flagged_dup: set[str] = set()
    flagged_any: set[str] = set()
    quality: dict[str, dict[str, float]] = defaultdict(dict)
    for f in flags:
        name = folder_of.get(f.object_id)
        if f.kind in DUPLICATE_KINDS + RELATION_KINDS and f.pair_object_id in folder_of:
            predicted[frozenset((name, folder_of[f.pair_object_id]))].add(f.kind)
            flagged_any.add(name)  # type: ignore[arg-type]
            if f.kind in DUPLICATE_KINDS:
                flagged_dup.add(name)  # type: ignore[arg-type]
        if f.kind in QUALITY_KINDS:
            quality[name][f.kind] = float(f.score)  # type: ignore[index]

    def correct(pair: frozenset[str]) -> bool:
        a, b = tuple(pair)
        return a in group_of and group_of.get(a) == group_of.get(b)

    def expected(pair: frozenset[str], kind: str) -> bool:
        wanted = (COLOUR_VARIANT,) if kind in VARIANT_TRAPS else DUPLICATE_KINDS
        return bool(predicted.get(pair, set()) & set(wanted))

    hits = [p for p in predicted if correct(p)]
    broken = [b["folder"] for b in truth.get("broken", []) if b["folder"] in id_of]
    clean = [n for n in id_of if n not in group_of and n not in set(broken)]
    clean_flagged = sorted(n for n in clean if n in flagged_dup)
    per_kind = {}
    for _, kind in TRAP_KINDS:
        pairs = [p for p, k in true_pairs.items() if k == kind]
        copies = {n for n, k in copy_kind.items() if k == kind}
        touching = [p for p in predicted if p & copies]
        found = sum(expected(p, kind) for p in pairs)
        per_kind[kind] = {
            "expected": "colour_variant" if kind in VARIANT_TRAPS else "duplicate",
            "planted": len(pairs), "found": found,
            "recall": round(found / len(pairs), 4) if pairs else None,
            "precision": round(sum(correct(p) for p in touching) / len(touching), 4) if touching else None,
            "flags": sorted({k for p in pairs for k in predicted.get(p, ())}),
        }
    planted_quality = [n for n in truth.get("mesh_quality", []) if n in id_of]
    return {
        "ground_truth": str(gt_path),
        "pairs_planted": len(true_pairs),
        "pairs_predicted": len(predicted),
        "pairs_correct": len(hits),  # predicted pairs within one planted group (copies of one original too)
        "pairs_found": sum(expected(p, k) for p, k in true_pairs.items()),  # planted pairs found, the recall's numerator
        "precision": round(len(hits) / len(predicted), 4) if predicted else 1.0,
        "recall": round(sum(expected(p, k) for p, k in true_pairs.items()) / len(true_pairs), 4) if true_pairs else 1.0,
        "by_trap": per_kind,
        "missed_pairs": sorted(sorted(p) for p, k in true_pairs.items() if not expected(p, k)),
        "false_pairs": sorted(sorted(p) for p in predicted if not correct(p)),
        "false_pair_kinds": {" | ".join(sorted(p)): sorted(k) for p, k in predicted.items() if not correct(p)},
        # of the predicted pairs with a duplicate kind (those exclude one object), the share that is correct
        "duplicate_precision": (round(sum(correct(p) for p, k in predicted.items() if k & set(DUPLICATE_KINDS))
                                      / max(1, sum(bool(k & set(DUPLICATE_KINDS)) for k in predicted.values())), 4)),
        "broken_planted": len(broken),
        "broken_flagged": sum(DEGENERATE in quality.get(b, {}) for b in broken),
        "clean_objects": len(clean),
        "clean_with_duplicate_flag": len(clean_flagged),
        "clean_flag_rate": round(len(clean_flagged) / len(clean), 4) if clean else 0.0,
        "clean_flagged": clean_flagged,
        "clean_paired": sorted(n for n in clean if n in flagged_any),
        "variant_pairs": sum(COLOUR_VARIANT in k for k in predicted.values()),
        "possible_copies": sum(POSSIBLE_COPY in k for k in predicted.values()),
        "mesh_quality_planted": [
            {"folder": n, "status": status_of[n], "mesh_quality": quality.get(n, {}).get(MESH_QUALITY),
             "degenerate": DEGENERATE in quality.get(n, {})} for n in planted_quality
        ],
    }

