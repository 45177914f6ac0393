"""Count targets: the number of *visible* counted objects a scene should keep, total and per class (issue 37).

The paper draws the number *spawned* (n ~ UniformInt[30, 200], ``[scene] n_objects``) and the visible count
follows from physics and occlusion. A count target instead names a distribution of visible counts:

- ``paper``: no target (the paper's rule, the default; the sampler's spawned-count path is untouched);
- ``uniform:A-B``: the total uniform over the integers A..B;
- ``histogram:PATH``: the total drawn from a text file of ``count weight`` lines (``#`` comments,
  commas or spaces), e.g. shaped like a benchmark's per-image counts, or from a benchmark's own annotation
  JSON (COCO instances, FSC-147's ``points``, a mixcount dataset's ``instances_<split>.json``:
  :mod:`mixcount.counts.benchmark_files`), whose per-image per-category counts also give the class split;

optionally followed by ``,imbalance:R1-R2`` for the per-class split: each scene draws a ratio R in
[R1, R2] and splits the total so the largest class holds about R times the smallest (class weights
geometric between 1 and R, in a random class order). Without it the split is the sampler's stars-and-bars
(uniform over the compositions with every class >= 1).

Everything is drawn from ``numpy.random.default_rng([scene seed, COUNT_TARGET_STREAM])``: a generator of its
own, so the target is reproducible by seed and the sampler's main stream draws what it always drew.
:func:`spawn_counts` turns a class's visible target into the number spawned (the retention prior of the
config: ``count_spawn_factor`` per floor / container scene); the worker then takes out the surplus
(:mod:`mixcount.counts.worker_decisions`), or tops a short class up from the bodies
:func:`reserve_counts` holds out of the first settle (:mod:`mixcount.engine.count_topup`).
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from mixcount.counts.benchmark_files import MAX_COUNT, FileImage, histogram_of, looks_like_json, read_annotation_file
from mixcount.errors import ConfigError

COUNT_TARGET_STREAM = 37  # the count target's generator: default_rng([scene seed, COUNT_TARGET_STREAM])
PAPER = "paper"
_NUMBER = r"([0-9]+(?:\.[0-9]*)?|\.[0-9]+)"


@dataclass(frozen=True)
class CountDistribution:
    """A parsed count target: ``kind`` paper | uniform | histogram, the support and weights of the total,
    and the per-class ``imbalance`` range (None: stars-and-bars); ``images``: per image of an annotation
    file its per-category counts, largest first (empty for a text histogram or a uniform target)."""

    kind: str
    text: str
    counts: tuple[int, ...] = ()
    weights: tuple[float, ...] = ()
    imbalance: Optional[tuple[float, float]] = None
    images: tuple[FileImage, ...] = ()

    @property
    def is_paper(self) -> bool:
        return self.kind == PAPER

    def probabilities(self) -> NDArray[Any]:
        w = np.asarray(self.weights, dtype=np.float64)
        return np.asarray(w / w.sum())

    def cdf(self, x: NDArray[Any]) -> NDArray[Any]:
        """The target's cumulative distribution at the integers ``x`` (for the Kolmogorov-Smirnov distance)."""
        c = np.cumsum(self.probabilities())
        idx = np.searchsorted(np.asarray(self.counts), np.asarray(x), side="right") - 1
        return np.asarray(np.where(idx >= 0, c[np.clip(idx, 0, len(c) - 1)], 0.0))


def _range(text: str, what: str, integer: bool) -> tuple[float, float]:
    m = re.fullmatch(rf"\s*{_NUMBER}\s*-\s*{_NUMBER}\s*", text)
    if not m:
        raise ConfigError(f"count target: {what} must be LOW-HIGH, got {_shown(text)}")
    lo, hi = float(m.group(1)), float(m.group(2))
    if max(lo, hi) > MAX_COUNT:  # inf included: 400 digits read as a float
        raise ConfigError(f"count target: {what} {_shown(text)} goes past {MAX_COUNT:,}, the most this takes "
                          "(FSC-147's fullest image holds 3,731 objects)")
    if integer and (lo != int(lo) or hi != int(hi)):
        raise ConfigError(f"count target: {what} takes whole numbers, got {text!r}")
    if lo > hi:
        raise ConfigError(f"count target: {what} {text!r} has its low end above its high end")
    return lo, hi


def _shown(line: str, limit: int = 60) -> str:
    """A bad line as an error shows it: repr, cut to ``limit`` characters (a one-line JSON file is MBs)."""
    return repr(line) if len(line) <= limit else repr(line[:limit]) + f"... ({len(line)} characters)"


def read_histogram(path: Path) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """``count weight`` per line (``#`` comments, blank lines, commas or spaces) -> sorted counts and weights."""
    if not path.is_file():
        raise ConfigError(f"count target histogram {path} does not exist")
    table: dict[int, float] = {}
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"count target histogram {path}: cannot read it as text ({type(exc).__name__})") from None
    for no, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p for p in re.split(r"[,\s]+", line) if p]
        try:
            count, weight = int(parts[0]), float(parts[1])
            if len(parts) != 2:
                raise ValueError
        except (ValueError, IndexError):
            raise ConfigError(f"{path}:{no}: expected 'count weight', got {_shown(line)}") from None
        if not 1 <= count <= MAX_COUNT or weight < 0 or not math.isfinite(weight):
            raise ConfigError(f"{path}:{no}: count must be 1 to {MAX_COUNT:,} and weight a finite number >= 0, "
                              f"got {_shown(line)}")
        table[count] = table.get(count, 0.0) + weight
    total = math.fsum(table.values())
    if not table or total <= 0:
        raise ConfigError(f"count target histogram {path} holds no positive weight")
    if not math.isfinite(total):
        raise ConfigError(f"count target histogram {path}: its weights add up past the largest number (use "
                          "smaller weights: only their ratios count)")
    keys = tuple(sorted(table))
    return keys, tuple(table[k] for k in keys)


def parse_count_target(text: str, base_dir: Optional[Path] = None) -> CountDistribution:
    """``paper`` | ``uniform:A-B`` | ``histogram:PATH``, each optionally ``,imbalance:R1-R2``; a relative
    histogram path is read from ``base_dir`` (the current folder when None). Bad text: ConfigError."""
    head, *rest = [p.strip() for p in str(text).split(",")]
    imbalance = None
    for part in rest:
        key, _, value = part.partition(":")
        if key != "imbalance":
            raise ConfigError(f"count target: unknown part {_shown(part)} (only imbalance:R1-R2 may follow)")
        imbalance = _range(value, "imbalance", integer=False)
        if imbalance[0] < 1.0:
            raise ConfigError(f"count target: the imbalance is max/min per scene, >= 1; got {_shown(value)}")
    kind, _, value = head.partition(":")
    if kind == PAPER and not value:
        if imbalance is not None:
            raise ConfigError("count target: an imbalance needs a target (uniform:A-B or histogram:PATH)")
        return CountDistribution(PAPER, text)
    if kind == "uniform":
        lo, hi = _range(value, "uniform", integer=True)
        if lo < 1:
            raise ConfigError(f"count target: uniform counts start at 1, got {_shown(value)}")
        counts = tuple(range(int(lo), int(hi) + 1))
        return CountDistribution("uniform", text, counts, (1.0,) * len(counts), imbalance)
    if kind in ("histogram", "hist"):
        path = Path(value)
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        if not path.is_file():
            raise ConfigError(f"count target histogram {path} does not exist")
        if looks_like_json(path):
            images = read_annotation_file(path)
            counts, weights = histogram_of(images)
            return CountDistribution("histogram", text, counts, weights, imbalance, tuple(images))
        counts, weights = read_histogram(path)
        return CountDistribution("histogram", text, counts, weights, imbalance)
    raise ConfigError(f"count target {_shown(str(text))}: expected paper, uniform:A-B or histogram:PATH "
                      "(optionally followed by ,imbalance:R1-R2)")


@functools.lru_cache(maxsize=8)
def count_distribution(text: str) -> CountDistribution:
    """:func:`parse_count_target` once per text (the sampler draws from it for every scene); a relative
    histogram path is read from the current folder (``compose --counts`` makes it absolute)."""
    return parse_count_target(text)


def draw_total(dist: CountDistribution, seed: int) -> int:
    """The scene's visible total, from the seed's own count-target stream."""
    rng = np.random.default_rng([int(seed), COUNT_TARGET_STREAM])
    return int(rng.choice(np.asarray(dist.counts), p=dist.probabilities()))


def _proportional(weights: NDArray[Any], total: int) -> list[int]:
    """``total`` over ``len(weights)`` classes, every class >= 1, the rest in proportion to ``weights``
    (largest remainder rounding)."""
    k = len(weights)
    spare = total - k  # every class holds one; the rest in proportion
    share = weights / weights.sum() * total - 1.0
    share = np.clip(share, 0.0, None)
    share = share / share.sum() * spare if share.sum() > 0 else np.full(k, spare / k)
    counts = np.floor(share).astype(int)
    order = np.argsort(-(share - counts), kind="stable")
    counts[order[: spare - int(counts.sum())]] += 1
    return [int(c) + 1 for c in counts]


def _file_image(dist: CountDistribution, rng: np.random.Generator, total: int) -> Optional[FileImage]:
    """One image of the annotation file with this total and two or more categories (None: none has)."""
    same = [img for img in dist.images if sum(img.counts) == total and len(img.counts) >= 2]
    return same[int(rng.integers(len(same)))] if same else None


def _by_size(image: FileImage, class_areas: Optional[Sequence[float]], k: int) -> Optional[NDArray[Any]]:
    """The image's per-category counts as weights in the scene's class order, by object size: the
    category of the image's largest objects (mean area) goes to the class of the largest objects
    (``class_areas``), and so on down; an image with another number of categories is resampled over the
    size ranks (log counts interpolated, so its largest / smallest ratio is kept). None when the file gives
    no areas or the scene none (the caller draws a random class order). A benchmark's image (and a paper
    scene, whose small objects are lost to occlusion more often) holds more or fewer of its large objects;
    in a random order a target read from the paper run's own file took 0.19 of its counted objects from
    the largest class against the paper's 0.41 (issue 48, docs/performance.md)."""
    if class_areas is None or len(class_areas) != k or min(image.areas) <= 0:
        return None
    by_area = np.argsort(-np.asarray(image.areas), kind="stable")  # categories, largest objects first
    ranked = np.asarray(image.counts, dtype=np.float64)[by_area]
    if len(ranked) != k:
        ranked = np.exp(np.interp(np.linspace(0.0, 1.0, k), np.linspace(0.0, 1.0, len(ranked)), np.log(ranked)))
    by_size = np.argsort(-np.asarray(class_areas, dtype=np.float64), kind="stable")  # classes, largest first
    out = np.empty(k)
    out[by_size] = ranked
    return out


def split_total(dist: CountDistribution, seed: int, total: int, n_classes: int,
                class_areas: Optional[Sequence[float]] = None) -> tuple[list[int], Optional[float]]:
    """``total`` over ``n_classes`` classes, every class >= 1 (the caller keeps n_classes <= total): the
    stars-and-bars composition, or with an imbalance range a drawn ratio R (returned) and counts
    proportional to R**(j / (k - 1)) in a random class order (largest remainder rounding). A target read
    from an annotation file (no imbalance given) takes an image of the file with the drawn total and two or
    more categories: its own per-category counts matched to the classes by object size when the file
    gives areas (``class_areas``: any measure proportional to the area one object of each class shows;
    resampled to ``n_classes``: :func:`_by_size`); without areas its counts in a random class order when
    it has ``n_classes`` categories, else its ratio (largest / smallest) as R; stars-and-bars when no such
    image exists (FSC-147: one class per image)."""
    rng = np.random.default_rng([int(seed), COUNT_TARGET_STREAM, 1])
    k = int(n_classes)
    if k <= 1:
        return [int(total)], None
    image = _file_image(dist, rng, int(total)) if dist.imbalance is None and dist.images else None
    if image is not None:
        ratio = float(image.counts[0]) / float(image.counts[-1])
        ranked = _by_size(image, class_areas, k)
        if ranked is not None:
            return _proportional(ranked, int(total)), ratio
        if len(image.counts) == k:
            return _proportional(np.asarray(image.counts, dtype=np.float64)[rng.permutation(k)], int(total)), ratio
    elif dist.imbalance is None:
        cuts = np.sort(rng.choice(np.arange(1, total), size=k - 1, replace=False))
        return [int(c) for c in np.diff(np.concatenate([[0], cuts, [total]]))], None
    else:
        ratio = float(rng.uniform(dist.imbalance[0], dist.imbalance[1]))
    weights = ratio ** (np.arange(k) / (k - 1))
    return _proportional(weights[rng.permutation(k)], int(total)), ratio


def draw_elevations(seed: int, n_cameras: int, elevation_range: Sequence[float]) -> list[float]:
    """A count target's camera elevations (degrees), uniform in ``elevation_range`` as the paper's, drawn
    from ``default_rng([seed, COUNT_TARGET_STREAM, 2])`` before the spawn (which is sized for them)."""
    rng = np.random.default_rng([int(seed), COUNT_TARGET_STREAM, 2])
    return [float(rng.uniform(elevation_range[0], elevation_range[1])) for _ in range(int(n_cameras))]


def elevation_factor(elevation_deg: float, occlusion: float) -> float:
    """1 / (1 - occlusion x cos(elevation)): the share a camera at this elevation is expected to lose to
    occlusion grows as it looks from the side (measured: 0.1-0.46 of the counted bodies occluded below 35
    degrees, 0-0.16 above 55; docs/performance.md)."""
    return 1.0 / (1.0 - float(occlusion) * math.cos(math.radians(float(elevation_deg))))


def spawn_counts(targets: Sequence[int], factor: float, extra: int, sizes: Optional[Sequence[float]] = None,
                 size_exponent: float = 0.0, sqrt_extra: float = 0.0) -> list[int]:
    """Bodies spawned per class for its visible target (the retention prior with a margin; the worker takes
    the surplus out): ceil(target x factor x (largest class size / this class's size) ** size_exponent)
    + extra + ceil(sqrt_extra x sqrt(target)). Smaller classes lose more to occlusion by larger ones, and a
    small class's retention varies most from scene to scene (measured: docs/performance.md)."""
    ratios = [1.0] * len(targets)
    if sizes is not None and len(sizes) == len(targets) and min(sizes) > 0:
        ratios = [(max(sizes) / s) ** size_exponent for s in sizes]
    return [int(math.ceil(t * factor * r - 1e-9)) + int(extra) + int(math.ceil(sqrt_extra * math.sqrt(t) - 1e-9))
            for t, r in zip(targets, ratios)]


def reserve_counts(targets: Sequence[int], reserve: Sequence[float]) -> list[int]:
    """Bodies per class held out of the first settle for a top-up: ceil(reserve[0] x target) + reserve[1].
    They are the class's last instances in the spec (:func:`reserve_instances`); a short class is topped up
    from them by dropping them onto the settled pile, the rest never enter the scene."""
    return [int(math.ceil(float(reserve[0]) * int(t) - 1e-9)) + int(reserve[1]) for t in targets]


def reserve_instances(classes: Sequence[int], instance_ids: Sequence[int], reserve: Sequence[int]) -> list[int]:
    """The instance ids held in reserve: per class ``c`` its ``reserve[c]`` highest instance ids (the
    sampler fills spawn positions in instance order, so these are the top of the spawn column)."""
    out: list[int] = []
    for c, r in enumerate(reserve):
        ids = sorted(int(i) for i, k in zip(instance_ids, classes) if int(k) == c)
        out.extend(ids[len(ids) - int(r):] if int(r) > 0 else [])
    return sorted(out)


def target_record(total: int, per_class: Sequence[int], ratio: Optional[float], dist: CountDistribution,
                  factor: float, short_tolerance: Sequence[float], class_short_tolerance: int,
                  min_object_px: float, *, reserve: Sequence[int], topup_rounds: int, rest_frames: int,
                  rest_tolerance: float, rest_verify: bool = False) -> dict[str, Any]:
    """What the spec records: the distribution's text, the drawn total, per class index, the drawn
    imbalance ratio, the spawn factor used and how short the worker may end (``short_total``: max(a, b x
    total) objects, ``short_class``) before the scene is regenerated, ``min_object_px`` (below it the
    worker records the image side its objects would need), the reserve bodies per class and the top-up
    rounds allowed, and the rest check's frames and tolerance (x size); ``rest_verify`` (recorded only when
    true): the worker checks the finished pile once more, whole, and records what would fall."""
    short = max(float(short_tolerance[0]), float(short_tolerance[1]) * total)
    verify = {"rest_verify": True} if rest_verify else {}
    return {**verify, "distribution": dist.text, "total": int(total), "per_class": [int(c) for c in per_class],
            "imbalance": None if ratio is None else round(ratio, 6), "spawn_factor": float(factor),
            "short_total": int(math.floor(short)), "short_class": int(class_short_tolerance),
            "min_object_px": float(min_object_px), "reserve": [int(r) for r in reserve],
            "topup_rounds": int(topup_rounds), "rest_frames": int(rest_frames),
            "rest_tolerance": float(rest_tolerance)}


def per_category(record: Mapping[str, Any], class_category: Mapping[int, int]) -> dict[str, Any]:
    """metadata.json's ``count_target``: total and ``{category_id: n}`` (class index -> category id)."""
    per = {str(class_category[ci]): int(n) for ci, n in enumerate(record["per_class"])}
    return {"total": int(record["total"]), "per_class": per, "distribution": record["distribution"],
            "imbalance": record.get("imbalance"), "spawn_factor": record.get("spawn_factor")}
