"""A sampler pool straight from a generated demo library, without a catalog database.

Tests and ``bench/compose.py`` need realistic scenes (textured GLBs, a container) but not the whole
ingest / caption / split chain: :func:`pool_from_demo_library` reads the library's
``ground_truth.json`` (true Z-up dimensions) and returns :class:`~mixcount.scene.pool.ObjectRecord`
s, every working object in one split, ids in folder order.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from mixcount.scene.pool import ObjectRecord, fallback_captions


def pool_from_demo_library(root: Path, *, split: str = "train") -> list[ObjectRecord]:
    """ObjectRecords for every non-broken object of the demo library at ``root``."""
    root = Path(root)
    truth = json.loads((root / "ground_truth.json").read_text())
    broken = {b["folder"] for b in truth.get("broken", [])}
    pool = []
    for k, rec in enumerate(sorted(truth["objects"], key=lambda r: r["folder"]), start=1):
        folder = rec["folder"]
        if folder in broken:
            continue
        model = root / rec["model"]
        digest = hashlib.sha256(model.read_bytes()).hexdigest()
        name = folder.split("_")[-1].lower()
        caps = fallback_captions(f"{name} {rec['category']}", rec["category"])
        pool.append(ObjectRecord(
            object_id=k, name=folder, category=rec["category"], dims=tuple(float(v) for v in rec["dims_m"]),
            captions=caps, split=split, model_path=str(model.resolve()), content_hash=digest,
            container=bool(rec["container"]), source_units=rec.get("units"), source_up_axis=rec.get("up_axis"),
        ))
    return pool


def ensure_demo_pool(root: Path, *, seed: int = 0, split: str = "train") -> list[ObjectRecord]:
    """Generate the demo library at ``root`` unless it is already there, then return its pool.

    The benchmarks reuse a library across runs with ``--work DIR``; generating it is deterministic.
    """
    from mixcount.demo.library import generate_demo_library

    root = Path(root)
    if not (root / "ground_truth.json").exists():
        generate_demo_library(root, seed=seed)
    return pool_from_demo_library(root, split=split)
