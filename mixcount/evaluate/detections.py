"""Detection-style predictions (COCO results) turned into counts for ``mixcount evaluate``.

Detection counters (CountGD, GroundingDINO-based models, DAVE/GeCo in detection mode) emit the COCO
results format: a JSON list of ``{"image_id", "category_id", "bbox": [x, y, w, h], "score"}`` rows, one
per detected object (``segmentation`` may stand in for ``bbox``). The predicted count of a pair
(image, category) is the number of its rows whose score is strictly above the threshold
(``--score-threshold``; CountGD keeps boxes with confidence ``> box_threshold`` the same way). A pair with
detections that all fall at or below the threshold is predicted 0; a pair with no row at all is a
missing pair, scored 0 and reported as such by the metrics.

A file is read as detections when its rows carry ``score`` and ``bbox``/``segmentation`` and none of the
count-file keys (``count``, ``boxes``, ``points``); anything else goes to the count-file parser.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any, Optional

from mixcount.errors import PredictionError
from mixcount.evaluate.metrics import PredictionRow, is_int, parse_predictions, read_json

DEFAULT_SCORE_THRESHOLD = 0.5
_COUNT_KEYS = ("count", "boxes", "points")


def _rows(doc: Any) -> Any:
    if isinstance(doc, dict) and isinstance(doc.get("predictions"), list):
        return doc["predictions"]
    return doc


def is_detection_document(doc: Any) -> bool:
    """True when ``doc`` is a non-empty list of COCO result rows (score + bbox/segmentation, no counts)."""
    rows = _rows(doc)
    if not isinstance(rows, list) or not rows:
        return False
    return all(isinstance(r, dict) and "score" in r and ("bbox" in r or "segmentation" in r)
               and not any(k in r for k in _COUNT_KEYS) for r in rows)


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def detection_rows(doc: Any, score_threshold: float = DEFAULT_SCORE_THRESHOLD,
                   source: str = "<memory>") -> list[PredictionRow]:
    """One PredictionRow per (image, category) with detections: the count of rows scoring above the
    threshold. Rows are checked (integer ids, finite score, four finite bbox numbers)."""
    if not _finite(score_threshold):
        raise PredictionError(f"score threshold must be a finite number, got {score_threshold!r}")
    above: dict[tuple[int, int], int] = defaultdict(int)
    seen: dict[tuple[int, int], int] = defaultdict(int)
    for i, r in enumerate(_rows(doc)):
        where = f"{source}: detection {i}"
        img_id, cat_id = r.get("image_id"), r.get("category_id")
        if not is_int(img_id) or not is_int(cat_id):
            raise PredictionError(f"{where}: needs integer 'image_id' and 'category_id'")
        if not _finite(r["score"]):
            raise PredictionError(f"{where}: 'score' must be a finite number, got {r['score']!r}")
        if "bbox" in r:
            box = r["bbox"]
            if not isinstance(box, list) or len(box) != 4 or not all(_finite(v) for v in box):
                raise PredictionError(f"{where}: 'bbox' must be [x, y, w, h] of finite numbers, got {box!r}")
        pair = (img_id, cat_id)
        seen[pair] += 1
        if r["score"] > score_threshold:
            above[pair] += 1
    return [PredictionRow(i, c, float(above.get((i, c), 0)),
                          {"detections": n, "score_threshold": score_threshold})
            for (i, c), n in sorted(seen.items())]


def load_prediction_file(path: str | Path, score_threshold: Optional[float] = None) -> list[PredictionRow]:
    """Rows of a prediction file: count rows (docs/evaluate.md) or COCO detection results."""
    doc = read_json(Path(path), PredictionError)
    if is_detection_document(doc):
        return detection_rows(doc, DEFAULT_SCORE_THRESHOLD if score_threshold is None else score_threshold,
                              str(path))
    return parse_predictions(doc, str(path))
