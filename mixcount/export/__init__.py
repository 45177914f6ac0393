"""Exports of a composed dataset into the layouts counting codebases train on (docs/export.md).

``export_dataset(dataset, fmt, out, split=..., tier=..., progress=...)`` reads a ``mixcount compose``
folder (never writing to it) and writes one format into ``out``:

- ``fsc147``   FSC-147 layout (LOCA, DAVE, GeCo, CounTR, FamNet) with PairTally negatives (:mod:`.fsc147`)
- ``countgd``  ODVG JSONL + label map for training, CountGD's COCO-with-exemplars for validation (:mod:`.countgd`)
- ``hf``       Hugging Face dataset: Parquet shards and a README dataset card (:mod:`.hf`)
- ``fiftyone`` COCO with masks and attributes for FiftyOne's ``COCODetectionDataset`` importer (:mod:`.fiftyone`)

Every export carries ``ATTRIBUTION.json`` / ``ATTRIBUTION.md`` (:mod:`.attribution`) and a
``mixcount_export.json`` manifest; reruns resume and leave what a fresh run would (:mod:`.outputs`).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Optional

from mixcount.errors import ExportError

FORMATS = ("fsc147", "countgd", "hf", "fiftyone")


def export_dataset(dataset: Path | str, fmt: str, out: Path | str, *, split: Optional[str] = None,
                   tier: str = "concise", progress: Any = None) -> dict[str, Any]:
    """Export the composed dataset at ``dataset`` as ``fmt`` into ``out``; returns the export manifest."""
    from mixcount.export.reader import ComposedDataset, check_tier

    if fmt not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r} (choose one of {', '.join(FORMATS)})")
    check_tier(tier)
    ds = ComposedDataset(dataset)
    module = importlib.import_module(f"mixcount.export.{fmt}")
    return getattr(module, f"export_{fmt}")(ds, out, split=split, tier=tier, progress=progress)
