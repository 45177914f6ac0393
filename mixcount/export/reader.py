"""Read-only view of a composed dataset folder, shared by every exporter.

The source of truth is ``OUT/annotations/instances_<split>.json`` (the merged COCO that ``compose``
writes: images carry ``scene_id`` and their internal ``exemplars``, annotations ``is_distractor`` and
``visibility``, categories the three caption tiers) plus the RGB files it names. Nothing here writes.

Vocabulary used by the exporters:
- an **image** is one COCO image (one scene and camera);
- a **class** of an image is a category with at least one counted (non-distractor) annotation there;
- a **sample** is one (image, class) pair, the unit FSC-147 style datasets label (one class per image).
  Its count is the number of annotations of that category in the image, the count ``mixcount evaluate``
  scores (the MixCount protocol), which equals the counted instances unless a distractor happens to be
  the same catalog object.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Optional, Sequence

from mixcount.dataset.coco_stream import members
from mixcount.errors import ExportError
from mixcount.scene.spec import TIERS as CAPTION_TIERS  # the one caption-tier tuple

N_EXEMPLARS = 3
_SPLIT_FILE = re.compile(r"^instances_(?P<split>.+)\.json$")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def image_key(scene_id: str, file_name: str) -> str:
    """The file-safe name of a dataset image (:attr:`DatasetImage.key`) from its scene id and file name."""
    stem = Path(str(file_name)).stem
    return _UNSAFE.sub("_", scene_id if stem == "rgb" else f"{scene_id}_{stem}")


def check_tier(tier: str) -> str:
    if tier not in CAPTION_TIERS:
        raise ExportError(f"unknown caption tier {tier!r} (choose one of {', '.join(CAPTION_TIERS)})")
    return tier


def caption(category: Mapping[str, Any], tier: str) -> str:
    """The category's caption at ``tier`` (short / concise / detailed); its name when the tier is missing."""
    check_tier(tier)
    text = category.get(tier) or category.get("name") or f"category {category['id']}"
    return " ".join(str(text).split())  # one line, single spaces: class files are TAB/line separated


@dataclass(frozen=True)
class DatasetImage:
    """One COCO image of a split with its annotations (file order) and categories by id."""

    split: str
    record: Mapping[str, Any]
    annotations: Sequence[Mapping[str, Any]]
    categories: Mapping[int, Mapping[str, Any]]
    path: Path
    _by_id: Mapping[int, Mapping[str, Any]] = field(repr=False, default_factory=dict)

    @property
    def id(self) -> int:
        return int(self.record["id"])

    @property
    def width(self) -> int:
        return int(self.record["width"])

    @property
    def height(self) -> int:
        return int(self.record["height"])

    @property
    def scene_id(self) -> str:
        return str(self.record.get("scene_id") or f"image_{self.id:06d}")

    @property
    def key(self) -> str:
        """File-safe name unique across the dataset: the scene id, plus the RGB file's stem when a scene
        has several cameras (``scenes/<id>/rgb.png`` -> ``<id>``; ``.../rgb_cam_1.png`` -> ``<id>_rgb_cam_1``)."""
        return image_key(self.scene_id, str(self.record["file_name"]))

    def classes(self) -> list[int]:
        """Category ids with a counted annotation in this image, ascending."""
        return sorted({int(a["category_id"]) for a in self.annotations if not a.get("is_distractor", False)})

    def of_category(self, category_id: int) -> list[Mapping[str, Any]]:
        """Every annotation of ``category_id`` in this image (distractors of that category included)."""
        return [a for a in self.annotations if int(a["category_id"]) == category_id]

    def count(self, category_id: int) -> int:
        return len(self.of_category(category_id))

    def exemplar_ranking(self, category_id: int) -> list[Mapping[str, Any]]:
        """The image's internal exemplars of the class, best first (``images[].exemplars``); without that
        record, counted annotations ranked by ``exemplar_score`` (ties by id)."""
        for ex in self.record.get("exemplars") or []:
            if int(ex["category_id"]) == category_id:
                anns = [self._by_id[int(i)] for i in ex["annotation_ids"] if int(i) in self._by_id]
                if anns:
                    return anns
        counted = [a for a in self.of_category(category_id) if not a.get("is_distractor", False)]
        return sorted(counted or self.of_category(category_id),
                      key=lambda a: (-float(a.get("exemplar_score", 0.0)), int(a["id"])))[:N_EXEMPLARS]

    def exemplars(self, category_id: int, n: int = N_EXEMPLARS) -> list[Mapping[str, Any]]:
        """Exactly ``n`` exemplar annotations of the class: the ranking, repeated in order when the class
        has fewer than ``n`` instances (FSC-147 loaders and CountGD need three boxes)."""
        ranked = self.exemplar_ranking(category_id)
        if not ranked:
            raise ExportError(f"image {self.id} ({self.scene_id}) has no annotation of category {category_id}")
        return [ranked[k % len(ranked)] for k in range(n)]

    def cross_scene_exemplars(self, category_id: int, n: int = N_EXEMPLARS) -> list[Mapping[str, Any]]:
        """Up to ``n`` of the class's cross-scene exemplars (the paper's crops of the same object from other
        scenes of the split; :mod:`mixcount.dataset.external_exemplars`) that come from other scenes than
        this image's; fewer when the object is in fewer other scenes, none in a dataset merged before."""
        from mixcount.dataset.external_exemplars import cross_scene_for_image

        return cross_scene_for_image(self.categories[category_id], self.scene_id, n)


@dataclass
class _SplitIndex:
    """What one streaming pass over a split's COCO file keeps: everything but the annotations."""

    images: list[Mapping[str, Any]]  # in id order
    categories: list[Mapping[str, Any]]
    n_samples: int  # (image, counted category) pairs
    grouped: bool  # annotations come image by image, in image-id order (the merge writes them so)


class ComposedDataset:
    """A ``mixcount compose`` output folder, opened read-only.

    A split's merged COCO file is read in streaming passes (:mod:`mixcount.dataset.coco_stream`): one pass
    keeps the images, categories and sample count; :meth:`images` then reads the annotations again,
    one image's at a time. At 58,000 scenes the file is ~3.4 GB of mostly RLE masks, which
    ``json.loads`` would hold whole (docs/export.md). A file whose annotations are not grouped by image
    in image order (not written by the merge) is read whole instead."""

    def __init__(self, root: Path | str):
        self.root = Path(root)
        ann_dir = self.root / "annotations"
        if not self.root.is_dir():
            raise ExportError(f"{self.root}: no such dataset folder")
        files = {}
        if ann_dir.is_dir():
            for p in sorted(ann_dir.iterdir()):
                m = _SPLIT_FILE.match(p.name)
                if m and p.is_file():
                    files[m.group("split")] = p
        if not files:
            raise ExportError(f"{self.root}: not a composed mixcount dataset (no annotations/instances_<split>.json; "
                              "write one with `mixcount compose --out DIR`)")
        self.annotation_files: dict[str, Path] = files
        self._coco: dict[str, dict[str, Any]] = {}
        self._index: dict[str, _SplitIndex] = {}

    @property
    def splits(self) -> list[str]:
        return sorted(self.annotation_files)

    def select_splits(self, split: Optional[str]) -> list[str]:
        """``[split]`` when given (checked), else every split of the dataset."""
        if split is None:
            return self.splits
        if split not in self.annotation_files:
            raise ExportError(f"{self.root}: no split {split!r} (the dataset has {', '.join(self.splits)})")
        return [split]

    def coco(self, split: str) -> dict[str, Any]:
        """The split's whole COCO document, parsed at once (small datasets, and files not in merge order)."""
        if split not in self._coco:
            path = self.annotation_files[split]
            try:
                doc = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise ExportError(f"{path}: cannot read the COCO file ({exc})") from None
            for key in ("images", "annotations", "categories"):
                if not isinstance(doc.get(key), list):
                    raise ExportError(f"{path}: COCO key {key!r} is missing or not a list")
            self._coco[split] = doc
        return self._coco[split]

    def _members(self, split: str) -> Iterator[tuple[str, Any, bool]]:
        path = self.annotation_files[split]
        try:
            yield from members(path, ("images", "annotations"))
        except (OSError, ValueError) as exc:
            raise ExportError(f"{path}: cannot read the COCO file ({exc})") from None

    def _split_index(self, split: str) -> _SplitIndex:
        """One streaming pass: images, categories, the sample count and whether annotations are grouped."""
        if split in self._index:
            return self._index[split]
        path = self.annotation_files[split]
        images: list[Mapping[str, Any]] = []
        categories: Any = None
        seen: set[str] = set()
        pairs: set[tuple[int, int]] = set()
        last, grouped = -1, True
        for key, value, element in self._members(split):
            if key in ("images", "annotations", "categories"):
                if not element and not isinstance(value, list):
                    raise ExportError(f"{path}: COCO key {key!r} is missing or not a list")
                seen.add(key)
            if key == "images" and element:
                images.append(value)
            elif key == "annotations" and element:
                image_id = int(value["image_id"])
                grouped = grouped and image_id >= last
                last = image_id
                if not value.get("is_distractor", False):
                    pairs.add((image_id, int(value["category_id"])))
            elif key == "categories":
                categories = value
        missing = {"images", "annotations", "categories"} - seen
        if missing:
            raise ExportError(f"{path}: COCO key {sorted(missing)[0]!r} is missing or not a list")
        index = _SplitIndex(sorted(images, key=lambda r: int(r["id"])), list(categories), len(pairs), grouped)
        self._index[split] = index
        return index

    def categories(self, split: str) -> dict[int, Mapping[str, Any]]:
        return {int(c["id"]): c for c in self._split_index(split).categories}

    def n_images(self, split: str) -> int:
        return len(self._split_index(split).images)

    def _annotations_by_image(self, split: str) -> Iterator[tuple[int, list[Mapping[str, Any]]]]:
        """(image id, its annotations in file order), image by image in file order."""
        index = self._split_index(split)
        if not index.grouped:
            by_image: dict[int, list[Mapping[str, Any]]] = {}
            for a in self.coco(split)["annotations"]:
                by_image.setdefault(int(a["image_id"]), []).append(a)
            yield from sorted(by_image.items())
            return
        current: Optional[int] = None
        group: list[Mapping[str, Any]] = []
        for key, value, element in self._members(split):
            if key != "annotations" or not element:
                continue
            image_id = int(value["image_id"])
            if image_id != current:
                if current is not None:
                    yield current, group
                current, group = image_id, []
            group.append(value)
        if current is not None:
            yield current, group

    def images(self, split: str) -> Iterator[DatasetImage]:
        """The split's images in id order, each with its annotations; a missing RGB file is an error."""
        cats = self.categories(split)
        groups = self._annotations_by_image(split)
        pending = next(groups, None)
        for rec in self._split_index(split).images:
            image_id = int(rec["id"])
            while pending is not None and pending[0] < image_id:  # annotations of no listed image
                pending = next(groups, None)
            anns: list[Mapping[str, Any]] = []
            if pending is not None and pending[0] == image_id:
                anns = pending[1]
                pending = next(groups, None)
            path = self.root / str(rec["file_name"])
            if not path.is_file():
                raise ExportError(f"{path}: image of {self.annotation_files[split].name} image {rec['id']} is missing")
            yield DatasetImage(split, rec, anns, cats, path, {int(a["id"]): a for a in anns})

    def samples(self, split: str) -> Iterator[tuple[DatasetImage, int]]:
        """(image, class) pairs of the split: images in id order, classes ascending."""
        for img in self.images(split):
            for cid in img.classes():
                yield img, cid

    def count_samples(self, splits: Sequence[str]) -> int:
        return sum(self._split_index(s).n_samples for s in splits)

    def scene_ids(self, splits: Sequence[str]) -> list[str]:
        """Scene ids of the images of ``splits`` (what an export's attribution must cover)."""
        return sorted({str(img.get("scene_id")) for s in splits for img in self._split_index(s).images
                       if img.get("scene_id")})
