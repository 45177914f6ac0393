"""Fuzzing the count-target parsers users feed (issue 60): ``--counts`` text, text histograms, COCO
instances files and FSC-147 annotations. Whatever the input, the parser either returns a usable
distribution (counts 1..MAX_COUNT, finite weights summing to a positive number, draws and per-class
splits inside it) or raises one ConfigError; nothing else (OverflowError, RecursionError, TypeError...)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from fuzz_settings import NUMBER_TEXT, deep, dumps_loose, fuzz, json_values
from hypothesis import given
from hypothesis import strategies as st

from mixcount.counts.benchmark_files import MAX_COUNT
from mixcount.counts.targets import CountDistribution, draw_total, parse_count_target, split_total
from mixcount.errors import ConfigError


def check_usable(dist: CountDistribution, seed: int = 3) -> None:
    """What the sampler relies on: sorted support 1..MAX_COUNT, finite positive weights, draws inside."""
    if dist.is_paper:
        return
    counts = list(dist.counts)
    assert counts and counts == sorted(set(counts)) and 1 <= counts[0] and counts[-1] <= MAX_COUNT
    assert len(dist.weights) == len(counts) and all(math.isfinite(w) and w >= 0 for w in dist.weights)
    assert math.isclose(float(dist.probabilities().sum()), 1.0, rel_tol=1e-9)
    total = draw_total(dist, seed)
    assert total in counts
    for k in range(1, min(total, 4) + 1):
        areas = [float(2 ** j) for j in range(k)]
        per_class, ratio = split_total(dist, seed, total, k, areas)
        assert len(per_class) == k and sum(per_class) == total and min(per_class) >= 1
        assert ratio is None or (math.isfinite(ratio) and ratio >= 1.0)


def parse(text: str, base: Path | None = None) -> CountDistribution | None:
    try:
        dist = parse_count_target(text, base)
    except ConfigError as exc:
        assert len(str(exc)) < 600, str(exc)  # a cut of the text, never all of it (the CLI escapes line breaks)
        return None
    check_usable(dist)
    return dist


RANGE = st.builds(lambda a, b: f"{a}-{b}", NUMBER_TEXT, NUMBER_TEXT)
COUNT_TEXT = st.one_of(
    st.text(max_size=40),
    st.builds(lambda r: f"uniform:{r}", RANGE),
    st.builds(lambda r, i: f"uniform:{r},imbalance:{i}", RANGE, RANGE),
    st.builds(lambda h, tail: f"{h}{tail}", st.sampled_from(["paper", "uniform:", "histogram:", "hist:", "imbalance:"]),
              st.text(max_size=20)),
)


@fuzz(400)
@given(COUNT_TEXT)
def test_counts_option_text(text: str) -> None:
    parse(text)


LINE = st.one_of(
    st.builds(lambda c, w, sep: f"{c}{sep}{w}", NUMBER_TEXT, NUMBER_TEXT, st.sampled_from([" ", ",", "\t", " , "])),
    st.text(max_size=20),
    st.sampled_from(["# comment", "", "5 1 # trailing", "3", "1 2 3"]),
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_counts")


@fuzz(250)
@given(st.lists(LINE, max_size=12))
def test_text_histogram_files(folder: Path, lines: list[str]) -> None:
    path = folder / "hist.txt"
    path.write_text("\n".join(lines), encoding="utf-8", errors="surrogatepass")
    parse(f"histogram:{path}")


COCO_KEYS = st.sampled_from(["images", "annotations", "id", "image_id", "category_id", "area", "bbox", "iscrowd",
                             "is_distractor", "points", "categories"])
ANNOTATION = st.fixed_dictionaries(
    {"image_id": st.one_of(st.integers(0, 4), st.sampled_from(["0", None, [1], {"a": 1}, 1.0, True]))},
    optional={"category_id": st.one_of(st.integers(0, 3), st.sampled_from([None, [1], "c", 2.5])),
              "area": st.one_of(st.floats(), st.integers(-10, 10**400 // 10**380), st.sampled_from([None, "9", 0])),
              "bbox": st.one_of(st.lists(st.one_of(st.floats(), st.integers(-5, 50)), max_size=5), st.text(max_size=3)),
              "iscrowd": st.sampled_from([0, 1, True, None, "1"]),
              "is_distractor": st.booleans()})
COCO = st.fixed_dictionaries(
    {"images": st.one_of(st.lists(st.one_of(st.fixed_dictionaries({"id": st.one_of(st.integers(0, 4),
                                                                                   st.sampled_from([[0], None, "1"]))}),
                                            json_values(COCO_KEYS)), max_size=6), json_values(COCO_KEYS)),
     "annotations": st.one_of(st.lists(st.one_of(ANNOTATION, json_values(COCO_KEYS)), max_size=30),
                              json_values(COCO_KEYS))})
FSC = st.dictionaries(st.text(max_size=8), st.one_of(
    st.fixed_dictionaries({"points": st.one_of(st.lists(st.lists(st.floats(), max_size=2), max_size=20),
                                               json_values(COCO_KEYS))}),
    json_values(COCO_KEYS)), max_size=6)


@fuzz(300)
@given(st.one_of(COCO, FSC, json_values(COCO_KEYS)), st.sampled_from(["", ",imbalance:1-3", ",imbalance:2-2"]))
def test_coco_and_fsc147_annotation_files(folder: Path, doc: object, tail: str) -> None:
    path = folder / "ann.json"
    text = dumps_loose(doc)
    path.write_text(text if text[:1] in "[{" else f"[{text}]", encoding="utf-8")
    parse(f"histogram:{path}{tail}")


@pytest.mark.parametrize("text", [deep(100_000), deep(5_000, "{"), '{"images": [], "annotations": [' + deep(3000) + "]}",
                                  '{"a": {"points": [' + ",".join(["[1, 2]"] * (MAX_COUNT + 1)) + "]}}",
                                  '{"images": [{"id": 1}], "annotations": [{"image_id": 1, "area": 1' + "0" * 5000 + "}]}",
                                  '{"images": [{"id": 1}], "annotations": [{"image_id": 1, "area": NaN}, '
                                  '{"image_id": 1, "area": Infinity, "category_id": 2}]}'])
def test_deep_and_huge_annotation_files(folder: Path, text: str) -> None:
    path = folder / "deep.json"
    path.write_text(text, encoding="utf-8")
    dist = parse(f"histogram:{path}")
    if dist is not None:  # the NaN / Infinity areas: read as unknown, the counts still usable
        assert dist.counts == (2,) and np.all(np.isfinite(dist.images[0].areas))


def test_parsed_annotation_file_keeps_its_counts(folder: Path) -> None:
    """A control that the fuzzed reader still reads real content: two COCO images, one two-class."""
    doc = {"images": [{"id": 1}, {"id": 2}], "annotations": [
        {"image_id": 1, "category_id": 1, "area": 4.0}, {"image_id": 1, "category_id": 2, "area": 9.0},
        {"image_id": 1, "category_id": 2, "area": 9.0}, {"image_id": 2, "category_id": 1, "bbox": [0, 0, 2, 3]}]}
    path = folder / "real.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    dist = parse(f"histogram:{path}")
    assert dist is not None and dist.counts == (1, 3) and dist.weights == (1.0, 1.0)
    assert sorted(img.counts for img in dist.images) == [(1,), (2, 1)]
