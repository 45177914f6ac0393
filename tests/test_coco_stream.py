"""Streaming reads of merged COCO files (mixcount/dataset/coco_stream.py) and the export reader on top."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from mixcount.dataset.coco_stream import members
from mixcount.errors import ExportError
from mixcount.export.reader import ComposedDataset

DOC = {
    "info": {"description": "mixcount train", "nested": [{"a": [1, 2, {"b": None}]}, "x"]},
    "images": [{"id": i, "file_name": f"scenes/s{i}/rgb.png", "note": "quote \" and \\ and é ☃"}
               for i in range(1, 6)],
    "annotations": [{"id": k, "image_id": 1 + k // 3, "value": -1.25e-3 * k, "flag": k % 2 == 0, "none": None,
                     "segmentation": {"size": [4, 4], "counts": "0" * (k * 7)}} for k in range(15)],
    "empty": [],
    "categories": [{"id": 7, "name": "die"}, {"id": 9, "name": "coin"}],
    "last_number": 1234567890,
    "last_literal": True,
}


def _reassemble(path: Path, streamed: tuple[str, ...], chunk: int) -> dict:
    out: dict = {}
    for key, value, element in members(path, streamed, chunk=chunk):
        if element:
            out.setdefault(key, []).append(value)
        else:
            assert key not in out
            out[key] = value
    return out


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 64, 1 << 20])
def test_members_read_exactly_what_json_loads_reads_whatever_the_chunk(tmp_path: Path, chunk: int) -> None:
    path = tmp_path / "doc.json"
    path.write_text(json.dumps(DOC, ensure_ascii=False), encoding="utf-8")
    got = _reassemble(path, ("images", "annotations", "empty"), chunk)
    assert got == json.loads(path.read_text(encoding="utf-8"))
    # the same with white space everywhere (the merge writes none, other tools do)
    path.write_text(json.dumps(DOC, indent=3), encoding="utf-8")
    assert _reassemble(path, ("annotations",), chunk) == DOC


def test_members_yield_elements_one_at_a_time_in_file_order(tmp_path: Path) -> None:
    path = tmp_path / "doc.json"
    path.write_text(json.dumps(DOC), encoding="utf-8")
    seq = [(key, element) for key, _, element in members(path, ("annotations",), chunk=5)]
    assert seq[:2] == [("info", False), ("images", False)]
    assert seq[2:17] == [("annotations", True)] * 15
    assert [k for k, _ in seq[17:]] == ["empty", "categories", "last_number", "last_literal"]


@pytest.mark.parametrize("text, needle", [
    ('{"a": [1, 2', "found 'the end of the file'"),  # cut short inside a streamed array
    ('{"a": [1, {"b": 2', "Expecting"),  # ... inside one of its elements
    ('{"a": 1} {"b": 2}', "extra data"),
    ('[1, 2]', "expected '{'"),
    ('{"a": 1 "b": 2}', "expected '}'"),
])
def test_members_reject_what_is_not_one_json_object(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ValueError, match=needle):
        list(members(path, ("a",), chunk=3))


def _dataset(root: Path, *, shuffle: bool) -> ComposedDataset:
    """A composed-dataset folder: 4 images (one without annotations), annotations in merge order or shuffled."""
    anns = []
    for image_id, n in ((1, 3), (2, 0), (3, 4), (4, 2)):
        for k in range(n):
            anns.append({"id": len(anns) + 1, "image_id": image_id, "category_id": 7 + (k % 2) * 2,
                         "bbox": [k, k, 2, 2], "is_distractor": k == 3,
                         "segmentation": {"size": [8, 8], "counts": "abc"}})
    if shuffle:
        random.Random(0).shuffle(anns)
    images = [{"id": i, "file_name": f"scenes/scene_{i:06d}/rgb.png", "width": 8, "height": 8,
               "scene_id": f"scene_{i:06d}"} for i in (3, 1, 4, 2)]
    for rec in images:
        (root / rec["file_name"]).parent.mkdir(parents=True, exist_ok=True)
        (root / rec["file_name"]).write_bytes(b"png")
    (root / "annotations").mkdir(parents=True, exist_ok=True)
    doc = {"info": {}, "images": images, "annotations": anns,
           "categories": [{"id": 7, "name": "die"}, {"id": 9, "name": "coin"}]}
    (root / "annotations" / "instances_train.json").write_text(json.dumps(doc))
    return ComposedDataset(root)


def test_reader_streams_a_merged_split_and_reads_any_other_order_whole(tmp_path: Path) -> None:
    merged = _dataset(tmp_path / "merged", shuffle=False)
    other = _dataset(tmp_path / "other", shuffle=True)
    views = []
    for ds in (merged, other):
        images = [(img.id, img.scene_id, [a["id"] for a in img.annotations], img.classes()) for img in ds.images("train")]
        views.append((images, ds.count_samples(["train"]), ds.scene_ids(["train"]), ds.n_images("train"),
                      sorted(ds.categories("train"))))
    assert views[0][0] == [(1, "scene_000001", [1, 2, 3], [7, 9]), (2, "scene_000002", [], []),
                           (3, "scene_000003", [4, 5, 6, 7], [7, 9]), (4, "scene_000004", [8, 9], [7, 9])]
    assert views[0][1:] == (6, ["scene_000001", "scene_000002", "scene_000003", "scene_000004"], 4, [7, 9])
    # the shuffled file gives the same images, each with its annotations in file order
    assert [(i, s, sorted(a), c) for i, s, a, c in views[1][0]] == views[0][0]
    assert views[1][1:] == views[0][1:]
    assert merged._coco == {}  # streamed: the whole document was never loaded
    assert "train" in other._coco  # not in merge order: read whole


def test_reader_reports_a_broken_or_incomplete_coco_file(tmp_path: Path) -> None:
    ds = _dataset(tmp_path / "d", shuffle=False)
    path = ds.annotation_files["train"]
    path.write_text(path.read_text()[:-40])
    with pytest.raises(ExportError, match="cannot read the COCO file"):
        list(ComposedDataset(tmp_path / "d").images("train"))
    path.write_text(json.dumps({"images": [], "annotations": []}))
    with pytest.raises(ExportError, match="'categories' is missing"):
        ComposedDataset(tmp_path / "d").count_samples(["train"])


def test_spooled_members_write_the_bytes_write_json_writes(tmp_path: Path) -> None:
    from mixcount.export.outputs import ExportFolder

    src = tmp_path / "dataset"
    src.mkdir()
    folder = ExportFolder(tmp_path / "out", src, "test")
    images = [{"id": i, "name": f"é ☃ \"{i}\""} for i in range(1, 4)]
    anns = [{"id": k, "segmentation": {"counts": "a\\b" * k}, "v": [1.5, None, True]} for k in range(5)]
    with folder.spool() as sp_images, folder.spool() as sp_anns, folder.spool() as sp_empty, \
            folder.spool(lines=True, ensure_ascii=True) as sp_lines:
        for i in images:
            sp_images.append(i)
            sp_lines.append(i)
        for a in anns:
            sp_anns.append(a)
        folder.write_json_members("streamed.json", [("info", {"d": "x"}), ("images", sp_images),
                                                    ("annotations", sp_anns), ("empty", sp_empty), ("n", 3)])
        folder.write_spooled("lines.jsonl", sp_lines)
        assert (len(sp_images), len(sp_anns), len(sp_empty)) == (3, 5, 0)
    folder.write_json("whole.json", {"info": {"d": "x"}, "images": images, "annotations": anns, "empty": [], "n": 3})
    assert (folder.root / "streamed.json").read_bytes() == (folder.root / "whole.json").read_bytes()
    assert (folder.root / "lines.jsonl").read_text() == "".join(json.dumps(i) + "\n" for i in images)
    assert sorted(p.name for p in folder.root.iterdir()) == ["lines.jsonl", "streamed.json", "whole.json"]


def test_ground_truth_and_stats_stream_the_annotations_and_count_as_before(tmp_path: Path) -> None:
    from mixcount.errors import GroundTruthError
    from mixcount.evaluate.metrics import ground_truth_from_coco, load_ground_truth, read_coco
    from mixcount.evaluate.stats import compute_stats

    ds = _dataset(tmp_path / "d", shuffle=True)
    path = ds.annotation_files["train"]
    whole = json.loads(path.read_text())
    slim = read_coco(path, GroundTruthError, keep=("image_id", "category_id", "is_distractor"))
    assert [set(a) for a in slim["annotations"]] == [{"image_id", "category_id", "is_distractor"}] * 9
    assert slim["images"] == whole["images"] and slim["categories"] == whole["categories"]
    streamed, loaded = load_ground_truth(tmp_path / "d", "train"), ground_truth_from_coco(whole, str(path))
    assert (streamed.counts, streamed.counted) == (loaded.counts, loaded.counted)
    assert compute_stats(tmp_path / "d")["splits"]["train"]["objects"] == 8  # 9 annotations, one distractor
    path.write_text(path.read_text()[:-30])
    with pytest.raises(GroundTruthError, match="not valid JSON"):
        load_ground_truth(path)
