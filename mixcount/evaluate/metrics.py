"""Counting metrics under the MixCount protocol: MAE, RMSE, NAE and Acc10%.

Protocol (paper, supplementary "MixCount evaluation protocol"): the ground-truth count of a pair
(image, object type) is the number of COCO annotations of that category in that image, distractor
annotations included. A pair exists for every (image, category) with at least one annotation.

Metrics over the scored pairs i = 1..n with ground truth y_i and prediction ŷ_i:
  MAE   = mean |y_i - ŷ_i|
  RMSE  = sqrt(mean (y_i - ŷ_i)^2)
  NAE   = mean |y_i - ŷ_i| / y_i          over pairs with y_i > 0
  Acc10 = share of pairs with |y_i - ŷ_i| / y_i <= 0.1, over pairs with y_i > 0 (a fraction in [0, 1])

y = 0: NAE is undefined there, so pairs with y_i = 0 count in MAE and RMSE but are left out of the NAE
and Acc10 averages; they are reported apart as ``zero_pairs`` and ``zero_exact`` (share of them predicted
exactly 0). With y >= 1 everywhere (the paper's protocol, where pairs come from annotations) the numbers
are exactly the paper's. y = 0 pairs only exist when asked for (``score_absent``): prediction rows for a
known image and a known category that has no annotation in that image (e.g. a negative prompt).

Missing pairs (in the ground truth, absent from the predictions) are scored as ŷ = 0 and reported;
prediction rows for pairs not in the ground truth are reported as ``extra`` and not scored.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Collection, Iterable, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.errors import EvaluationError, GroundTruthError, PredictionError

ACC_THRESHOLD = 0.1
NO_VALUE = "(none)"  # group name of rows / pairs that lack the grouping field
PAIR_FIELDS = ("image_id", "category_id", "role")  # --by values that always partition the GT pairs

Pair = tuple[int, int]


# --------------------------------------------------------------------------------------------- ground truth


@dataclass(frozen=True)
class GroundTruth:
    """Counts per (image_id, category_id) from one COCO file, plus its images and categories by id."""

    counts: Mapping[Pair, int]
    counted: frozenset[Pair]  # pairs with at least one non-distractor annotation
    images: Mapping[int, Mapping[str, Any]]
    categories: Mapping[int, Mapping[str, Any]]
    source: str = "<memory>"

    def role(self, pair: Pair) -> str:
        """``counted`` (a non-distractor annotation), ``distractor`` (only distractors) or ``absent``."""
        if pair not in self.counts:
            return "absent"
        return "counted" if pair in self.counted else "distractor"


def is_int(value: Any) -> bool:
    """An int as JSON ids are (``True`` is not an id): shared by the COCO and detection readers."""
    return isinstance(value, int) and not isinstance(value, bool)


def read_json(path: Path, error: type[Exception]) -> Any:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read ({exc})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None


def read_coco(path: Path, error: type[Exception], keep: Optional[Collection[str]] = None) -> dict[str, Any]:
    """A COCO file's top-level members, its annotations streamed and, with ``keep``, each reduced to those
    keys as it is read: a merged file of 58,000 scenes at 1024² is ~3.4 GB of RLE masks, which
    :func:`read_json` would hold whole (docs/evaluate.md)."""
    from mixcount.dataset.coco_stream import members

    if not Path(path).is_file():
        raise error(f"{path}: file not found")
    doc: dict[str, Any] = {}
    try:
        for key, value, element in members(path, ("annotations",)):
            if not element:
                doc[key] = value
                continue
            if keep is not None and isinstance(value, dict):
                value = {k: value[k] for k in keep if k in value}
            doc.setdefault(key, []).append(value)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc.msg})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read ({exc})") from None
    except ValueError as exc:
        raise error(f"{path}: not a COCO file: {exc}") from None
    return doc


def ground_truth_from_coco(doc: Any, source: str = "<memory>") -> GroundTruth:
    """Count annotations per (image, category) in a COCO document (a dict) and check its structure."""
    if not isinstance(doc, dict):
        raise GroundTruthError(f"{source}: a COCO file must hold a JSON object, got {type(doc).__name__}")
    for key in ("images", "annotations", "categories"):
        if not isinstance(doc.get(key), list):
            raise GroundTruthError(f"{source}: COCO key {key!r} is missing or not a list")
    images: dict[int, Mapping[str, Any]] = {}
    for i, img in enumerate(doc["images"]):
        if not isinstance(img, dict) or not is_int(img.get("id")):
            raise GroundTruthError(f"{source}: images[{i}] has no integer 'id'")
        images[img["id"]] = img
    categories: dict[int, Mapping[str, Any]] = {}
    for i, cat in enumerate(doc["categories"]):
        if not isinstance(cat, dict) or not is_int(cat.get("id")):
            raise GroundTruthError(f"{source}: categories[{i}] has no integer 'id'")
        categories[cat["id"]] = cat
    counts: dict[Pair, int] = defaultdict(int)
    counted: set[Pair] = set()
    for i, ann in enumerate(doc["annotations"]):
        if not isinstance(ann, dict):
            raise GroundTruthError(f"{source}: annotations[{i}] is not an object")
        img_id, cat_id = ann.get("image_id"), ann.get("category_id")
        if not is_int(img_id) or not is_int(cat_id):
            raise GroundTruthError(f"{source}: annotations[{i}] needs integer 'image_id' and 'category_id'")
        if img_id not in images:
            raise GroundTruthError(f"{source}: annotations[{i}] refers to unknown image_id {img_id}")
        if cat_id not in categories:
            raise GroundTruthError(f"{source}: annotations[{i}] refers to unknown category_id {cat_id}")
        counts[(img_id, cat_id)] += 1
        if not ann.get("is_distractor", False):
            counted.add((img_id, cat_id))
    return GroundTruth(dict(counts), frozenset(counted), images, categories, source)


def load_ground_truth(path: str | Path, split: str = "test") -> GroundTruth:
    """Read a COCO file, or ``<dataset>/annotations/instances_<split>.json`` when ``path`` is a folder."""
    path = Path(path)
    if path.is_dir():
        path = path / "annotations" / f"instances_{split}.json"
        if not path.is_file():
            held = sorted(f.name[len("instances_"):-len(".json")] for f in path.parent.glob("instances_*.json"))
            raise GroundTruthError(f"{path}: not found (is this a mixcount dataset folder with a {split!r} split? "
                                   f"it holds {', '.join(held) or 'no split'})")
    doc = read_coco(path, GroundTruthError, keep=("image_id", "category_id", "is_distractor"))
    return ground_truth_from_coco(doc, str(path))


# ---------------------------------------------------------------------------------------------- predictions


@dataclass(frozen=True)
class PredictionRow:
    """One predicted count for (image_id, category_id); ``fields`` holds every other key of the row."""

    image_id: int
    category_id: int
    count: float
    fields: Mapping[str, Any] = field(default_factory=dict)


def _row_count(row: Mapping[str, Any], where: str) -> float:
    counts: list[tuple[str, float]] = []
    if "count" in row:
        c = row["count"]
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0:
            raise PredictionError(f"{where}: 'count' must be a finite number >= 0, got {c!r}")
        counts.append((f"'count' {float(c):g}", float(c)))
    for key, one in (("boxes", "box"), ("points", "point")):
        if key in row:
            if not isinstance(row[key], list):
                raise PredictionError(f"{where}: {key!r} must be a list, got {type(row[key]).__name__}")
            n = len(row[key])
            counts.append((f"{n} {one if n == 1 else key} in {key!r}", float(n)))
    if not counts:
        raise PredictionError(f"{where}: needs 'count', 'boxes' or 'points'")
    if len({c for _, c in counts}) > 1:
        raise PredictionError(f"{where}: its counts disagree (" + " vs ".join(k for k, _ in counts)
                              + "); give one of them, or make them agree")
    return counts[0][1]


def parse_predictions(doc: Any, source: str = "<memory>") -> list[PredictionRow]:
    """Check and parse a prediction document: a list of rows, or ``{"predictions": [rows]}``."""
    if isinstance(doc, dict):
        if "predictions" not in doc:
            raise PredictionError(f"{source}: expected a list of rows or an object with a 'predictions' list")
        doc = doc["predictions"]
    if not isinstance(doc, list):
        raise PredictionError(f"{source}: predictions must be a list of rows, got {type(doc).__name__}")
    rows = []
    for i, row in enumerate(doc):
        where = f"{source}: row {i}"
        if not isinstance(row, dict):
            raise PredictionError(f"{where}: must be an object, got {type(row).__name__}")
        img_id, cat_id = row.get("image_id"), row.get("category_id")
        if not is_int(img_id) or not is_int(cat_id):
            raise PredictionError(f"{where}: needs integer 'image_id' and 'category_id'")
        extra = {k: v for k, v in row.items() if k not in ("image_id", "category_id", "count", "boxes", "points")}
        rows.append(PredictionRow(int(img_id), int(cat_id), _row_count(row, where), extra))  # type: ignore[arg-type]
    return rows


def load_predictions(path: str | Path) -> list[PredictionRow]:
    """Read and check a prediction JSON file (format in docs/evaluate.md)."""
    return parse_predictions(read_json(Path(path), PredictionError), str(path))


# ------------------------------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class Scores:
    """Metrics over one set of scored pairs, plus the bookkeeping numbers the report shows."""

    mae: float | None
    rmse: float | None
    nae: float | None
    acc10: float | None
    pairs: int  # scored pairs (GT pairs, plus y = 0 pairs when score_absent)
    missing: int = 0  # GT pairs without a prediction (scored as 0)
    extra: int = 0  # prediction rows for pairs not in the GT (not scored)
    zero_pairs: int = 0  # scored pairs with y = 0 (left out of NAE and Acc10)
    zero_exact: float | None = None  # share of y = 0 pairs predicted exactly 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "mae": self.mae, "rmse": self.rmse, "nae": self.nae, "acc10": self.acc10, "pairs": self.pairs,
            "missing": self.missing, "extra": self.extra, "zero_pairs": self.zero_pairs,
            "zero_exact": self.zero_exact,
        }


def score_counts(y: Sequence[float] | NDArray[Any], y_hat: Sequence[float] | NDArray[Any]) -> Scores:
    """MAE, RMSE, NAE and Acc10 of predicted counts ``y_hat`` against true counts ``y`` (see module doc)."""
    y_arr = np.asarray(y, dtype=np.float64)
    p_arr = np.asarray(y_hat, dtype=np.float64)
    if y_arr.shape != p_arr.shape or y_arr.ndim != 1:
        raise ValueError("y and y_hat must be 1-D and of the same length")
    n = int(y_arr.size)
    if n == 0:
        return Scores(None, None, None, None, 0)
    err = np.abs(y_arr - p_arr)
    pos = y_arr > 0
    zero = int(n - pos.sum())
    nae = acc = zero_exact = None
    if pos.any():
        rel = err[pos] / y_arr[pos]
        nae = float(rel.mean())
        acc = float(np.mean(rel <= ACC_THRESHOLD + 1e-12))
    if zero:
        zero_exact = float(np.mean(p_arr[~pos] == 0))
    return Scores(
        mae=float(err.mean()), rmse=float(np.sqrt(np.mean(err**2))), nae=nae, acc10=acc, pairs=n,
        zero_pairs=zero, zero_exact=zero_exact,
    )


@dataclass(frozen=True)
class Evaluation:
    """Overall scores, per-group scores (when grouped) and examples of missing / extra pairs."""

    overall: Scores
    by: str | None = None
    groups: Mapping[str, Scores] = field(default_factory=dict)
    missing_examples: tuple[Pair, ...] = ()
    extra_examples: tuple[Pair, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        d = self.overall.as_dict()
        if self.by is not None:
            d["by"] = self.by
            d["groups"] = {k: v.as_dict() for k, v in self.groups.items()}
        d["missing_examples"] = [list(p) for p in self.missing_examples]
        d["extra_examples"] = [list(p) for p in self.extra_examples]
        return d


@dataclass
class _Tally:
    """(y, ŷ) lists and bookkeeping for one set of scored pairs."""

    y: list[float] = field(default_factory=list)
    p: list[float] = field(default_factory=list)
    missing: list[Pair] = field(default_factory=list)
    extra: list[Pair] = field(default_factory=list)

    def scores(self) -> Scores:
        s = score_counts(self.y, self.p)
        return Scores(s.mae, s.rmse, s.nae, s.acc10, s.pairs, len(self.missing), len(self.extra), s.zero_pairs, s.zero_exact)

    def merge(self, other: "_Tally") -> None:
        self.y += other.y
        self.p += other.p
        self.missing += other.missing
        self.extra += other.extra


def _index(rows: Iterable[tuple[int, PredictionRow]], what: str) -> dict[Pair, float]:
    """Rows (with their position in the prediction file) keyed by (image_id, category_id); a repeated
    pair is an error of the prediction file (it would be scored twice) that names both rows."""
    seen: dict[Pair, tuple[int, PredictionRow]] = {}
    for i, r in rows:
        key = (r.image_id, r.category_id)
        if key in seen:
            first, prev = seen[key]
            differing = sorted(k for k in set(prev.fields) | set(r.fields) if prev.fields.get(k) != r.fields.get(k))
            hint = f"; the rows differ in {', '.join(differing)}: group them with --by {differing[0]}" if differing else ""
            raise PredictionError(f"{what}: rows {first} and {i} both predict image_id {key[0]}, category_id "
                                  f"{key[1]} (one prediction per pair){hint}")
        seen[key] = (i, r)
    return {k: r.count for k, (_, r) in seen.items()}


def _tally(gt: GroundTruth, pairs: Sequence[Pair], pred: Mapping[Pair, float], score_absent: bool) -> _Tally:
    t = _Tally()
    for pair in pairs:
        t.y.append(float(gt.counts[pair]))
        if pair in pred:
            t.p.append(pred[pair])
        else:
            t.p.append(0.0)
            t.missing.append(pair)
    pair_set = set(pairs)
    for pair, value in sorted(pred.items()):
        if pair in pair_set:
            continue
        if score_absent and pair not in gt.counts and pair[0] in gt.images and pair[1] in gt.categories:
            t.y.append(0.0)
            t.p.append(value)
        else:
            t.extra.append(pair)
    return t


def _pair_value(gt: GroundTruth, pair: Pair, by: str) -> str:
    if by == "image_id":
        return str(pair[0])
    if by == "category_id":
        return str(pair[1])
    if by == "role":
        return gt.role(pair)
    for record in (gt.categories[pair[1]], gt.images[pair[0]]):
        if by in record:
            return _label(record[by])
    return NO_VALUE


def _label(value: Any) -> str:
    if value is None:
        return NO_VALUE
    if isinstance(value, (dict, list)):
        return json.dumps(value, sort_keys=True)
    return str(value)


def evaluate(
    gt: GroundTruth,
    rows: Sequence[PredictionRow],
    *,
    by: str | None = None,
    counted_only: bool = False,
    score_absent: bool = False,
    n_examples: int = 5,
    pred_source: str = "predictions",
) -> Evaluation:
    """Score prediction rows against the ground truth, optionally grouped by a field.

    ``by`` names a field of the prediction rows (prompt type, caption tier, ...): each group is then
    scored against all ground-truth pairs (missing ones as 0), and the overall scores pool every group.
    When no row carries the field, ``by`` may name a field of the GT categories or images (name,
    size_qualifier, scene_id, ...) or ``image_id`` / ``category_id`` / ``role`` (counted or distractor):
    the GT pairs are then partitioned by that value. ``counted_only`` drops pairs whose category is only
    present as distractors in that image (the paper's protocol keeps them). ``pred_source`` (the
    prediction file) is the file an error about the rows names.
    """
    pairs = sorted(p for p in gt.counts if not counted_only or p in gt.counted)
    groups: dict[str, Scores] = {}
    total = _Tally()
    row_mode = by is not None and by not in PAIR_FIELDS and any(by in r.fields for r in rows)
    if by is None or not row_mode:
        pred = _index(enumerate(rows), pred_source if by is None else f"{pred_source} (grouped by GT field {by!r})")
        if by is not None and by not in PAIR_FIELDS:
            known = any(by in c for c in gt.categories.values()) or any(by in i for i in gt.images.values())
            if not known:
                raise PredictionError(f"--by {by!r}: no prediction row, GT category or GT image has that field")
        total = _tally(gt, pairs, pred, score_absent)
        if by is not None:
            parts: dict[str, list[Pair]] = defaultdict(list)
            for pair in pairs:
                parts[_pair_value(gt, pair, by)].append(pair)
            absent: dict[str, dict[Pair, float]] = defaultdict(dict)  # y = 0 pairs, in their own value's group
            if score_absent:
                for p, v in pred.items():
                    if p not in gt.counts and p[0] in gt.images and p[1] in gt.categories:
                        absent[_pair_value(gt, p, by)][p] = v
            for value in sorted(set(parts) | set(absent)):
                sub = {p: pred[p] for p in parts[value] if p in pred}
                sub.update(absent[value])
                groups[value] = _tally(gt, parts[value], sub, score_absent).scores()
    else:
        by_value: dict[str, list[tuple[int, PredictionRow]]] = defaultdict(list)
        for i, r in enumerate(rows):
            by_value[_label(r.fields.get(by))].append((i, r))
        for value in sorted(by_value):
            t = _tally(gt, pairs, _index(by_value[value], f"{pred_source}, rows with {by}={value}"), score_absent)
            groups[value] = t.scores()
            total.merge(t)
    return Evaluation(
        overall=total.scores(), by=by, groups=groups,
        missing_examples=tuple(dict.fromkeys(total.missing))[:n_examples],
        extra_examples=tuple(dict.fromkeys(total.extra))[:n_examples],
    )


def perfect_predictions(gt: GroundTruth, **fields: Any) -> list[dict[str, Any]]:
    """Prediction rows equal to the ground truth (one per pair); ``fields`` are added to each row."""
    return [
        {"image_id": i, "category_id": c, "count": n, **fields} for (i, c), n in sorted(gt.counts.items())
    ]


def load_reference(reference: str | Path, *, split: str, evaluated: GroundTruth) -> GroundTruth:
    """The mean baseline's reference: a COCO file, or split ``split`` (train, as a rule) of a dataset
    folder. The split being evaluated is refused: its own mean count would leak the answer."""
    ref = load_ground_truth(reference, split=split)
    if Path(ref.source).resolve() == Path(evaluated.source).resolve():
        raise EvaluationError(
            f"--reference {reference} reads {ref.source}, the very split being evaluated: its mean count would "
            "leak the answer; give the training split (a dataset folder's train split is read by default)")
    return ref


def mean_predictions(gt: GroundTruth, reference: GroundTruth | None = None, **fields: Any) -> list[dict[str, Any]]:
    """The mean-count baseline: every GT pair predicted as the mean count over ``reference``'s pairs.

    Use the train split as ``reference`` for a fair baseline (the paper's tables report learned models;
    this is the floor any counting model should beat). Without one, the GT's own mean is used.
    """
    ref = reference or gt
    mean = float(np.mean(list(ref.counts.values()))) if ref.counts else 0.0
    return [{"image_id": i, "category_id": c, "count": mean, **fields} for (i, c) in sorted(gt.counts)]
