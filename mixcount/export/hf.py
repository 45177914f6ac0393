"""``--format hf``: a Hugging Face dataset (Parquet shards + README.md dataset card), loadable with
``datasets.load_dataset(DIR)`` or ``load_dataset("parquet", data_files=...)`` (docs/export.md).

One row per image. Shards are ``data/<split>-NNNNN-of-MMMMM.parquet`` (``ROWS_PER_SHARD`` images each),
written with ``datasets``' own ParquetWriter so the schema carries the ``datasets`` features (the image
column decodes to a PIL image). Columns:

- ``image`` (Image: PNG bytes of the render), ``image_id``, ``scene_id``, ``width``, ``height``
- ``objects``: per annotation ``id``, ``bbox`` (COCO [x, y, w, h]), ``point`` ([x, y], a visible pixel),
  ``category_id``, ``category`` (caption at the chosen tier), ``is_distractor``, ``visibility``,
  ``segmentation`` (COCO compressed RLE counts; the mask size is the image size)
- ``classes``: per counted class ``category_id``, ``caption`` (chosen tier), ``short``, ``concise``,
  ``detailed``, ``count`` (annotations of that category in the image, the count ``mixcount evaluate``
  scores) and ``exemplar_ids`` (annotation ids of its internal exemplars, best first)

The card's YAML gives ``license``, ``task_categories``, ``size_categories``, ``tags``, ``configs`` (data
files per split) and ``dataset_info`` (features, split sizes).
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any, Optional

from mixcount.dataset.attribution import write_attribution
from mixcount.export.object_points import object_point
from mixcount.export.outputs import ExportFolder
from mixcount.export.reader import ComposedDataset, DatasetImage, caption, check_tier
from mixcount.progress import ProgressReporter
from mixcount.scene.spec import TIERS

ROWS_PER_SHARD = 500
DATA = "data"
LICENSE = "cc-by-sa-4.0"  # the MixCount paper's dataset licence; ATTRIBUTION.md lists each object's own
TASK_CATEGORIES = ["object-detection", "zero-shot-object-detection"]
TAGS = ["counting", "object-counting", "class-agnostic-counting", "synthetic", "mixcount"]


def features() -> Any:
    from datasets import Features, Image, Sequence, Value

    return Features({
        "image": Image(),
        "image_id": Value("int64"),
        "scene_id": Value("string"),
        "width": Value("int32"),
        "height": Value("int32"),
        "objects": Sequence({
            "id": Value("int64"),
            "bbox": Sequence(Value("float32"), length=4),
            "point": Sequence(Value("float32"), length=2),
            "category_id": Value("int64"),
            "category": Value("string"),
            "is_distractor": Value("bool"),
            "visibility": Value("float32"),
            "segmentation": Value("string"),
        }),
        "classes": Sequence({
            "category_id": Value("int64"),
            "caption": Value("string"),
            "short": Value("string"),
            "concise": Value("string"),
            "detailed": Value("string"),
            "count": Value("int32"),
            "exemplar_ids": Sequence(Value("int64")),
        }),
    })


def row(img: DatasetImage, tier: str) -> dict[str, Any]:
    """One image's row (module docstring)."""
    objects: dict[str, list[Any]] = {k: [] for k in ("id", "bbox", "point", "category_id", "category",
                                                     "is_distractor", "visibility", "segmentation")}
    for a in img.annotations:
        cat = img.categories[int(a["category_id"])]
        objects["id"].append(int(a["id"]))
        objects["bbox"].append([float(v) for v in a["bbox"]])
        objects["point"].append(list(object_point(a)))
        objects["category_id"].append(int(a["category_id"]))
        objects["category"].append(caption(cat, tier))
        objects["is_distractor"].append(bool(a.get("is_distractor", False)))
        objects["visibility"].append(float(a.get("visibility", 1.0)))
        seg = a.get("segmentation") or {}
        counts = seg.get("counts", "")
        objects["segmentation"].append(counts if isinstance(counts, str) else "")
    classes: dict[str, list[Any]] = {k: [] for k in ("category_id", "caption", "short", "concise", "detailed",
                                                     "count", "exemplar_ids")}
    for cid in img.classes():
        cat = img.categories[cid]
        classes["category_id"].append(cid)
        classes["caption"].append(caption(cat, tier))
        for t in TIERS:
            classes[t].append(caption(cat, t))
        classes["count"].append(img.count(cid))
        classes["exemplar_ids"].append([int(a["id"]) for a in img.exemplar_ranking(cid)])
    return {"image": {"bytes": img.path.read_bytes(), "path": img.path.name}, "image_id": img.id,
            "scene_id": img.scene_id, "width": img.width, "height": img.height, "objects": objects,
            "classes": classes}


def size_category(n: int) -> str:
    """The Hub's size_categories bucket of ``n`` rows."""
    for limit, name in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M"),
                        (10_000_000, "1M<n<10M")):
        if n < limit:
            return name
    return "10M<n<100M"


def dataset_card(split_rows: dict[str, int], split_bytes: dict[str, int], tier: str, counts: dict[str, int]) -> str:
    """README.md: YAML metadata (license, task_categories, size_categories, configs, dataset_info) + text."""
    import yaml
    from datasets import DatasetInfo

    total = sum(split_rows.values())
    meta = {
        "license": LICENSE,
        "task_categories": TASK_CATEGORIES,
        "size_categories": [size_category(total)],
        "tags": TAGS,
        "pretty_name": "MixCount synthetic mixed-object counting dataset",
        "configs": [{"config_name": "default",
                     "data_files": [{"split": s, "path": f"{DATA}/{s}-*.parquet"} for s in sorted(split_rows)]}],
        "dataset_info": {**DatasetInfo(features=features())._to_yaml_dict(),
                         "splits": [{"name": s, "num_bytes": split_bytes[s], "num_examples": n}
                                    for s, n in sorted(split_rows.items())]},
    }
    body = f"""
# MixCount synthetic counting dataset

Photorealistic renders of several similar-looking object types per image, made by mixcount from
real 3D object captures, following the MixCount paper. Every counted
object is at least 60 % visible and has a box, a visible point and a mask; each counted class has
three-tier captions and internal exemplars.

- {total} images ({', '.join(f'{s}: {n}' for s, n in sorted(split_rows.items()))}),
  {counts['classes']} (image, class) pairs, {counts['objects']} counted objects.
- `objects.category` and `classes.caption` use the **{tier}** caption tier; `classes` holds all three.
- The count of a class in an image is `classes.count` (every annotation of that category in the image).

```python
from datasets import load_dataset
ds = load_dataset("path/to/this/folder")
row = ds["{min(split_rows)}"][0]
row["image"], row["classes"]["caption"], row["classes"]["count"]
```

## Licence and attribution

Released as {LICENSE}. The object models keep their own licences: see `ATTRIBUTION.md` and
`ATTRIBUTION.json` (every object, its source id and licence text). Check them before sharing.
"""
    return "---\n" + yaml.safe_dump(meta, sort_keys=False, allow_unicode=True) + "---\n" + body


def export_hf(ds: ComposedDataset, out: Path | str, *, split: Optional[str] = None, tier: str = "concise",
              progress: Optional[ProgressReporter] = None) -> dict[str, Any]:
    """Write the Hugging Face export of ``ds`` into ``out``; returns the manifest (figures included)."""
    from datasets.arrow_writer import ParquetWriter

    from mixcount.progress import as_reporter

    check_tier(tier)
    bar = as_reporter(progress)
    splits = ds.select_splits(split)
    folder = ExportFolder(out, ds.root, "hf")
    feats = features()
    split_rows: dict[str, int] = {}
    shard_names: list[str] = []
    counts = {"classes": 0, "objects": 0}
    total = sum(ds.n_images(s) for s in splits)
    bar.start("export hf", total)
    try:
        for s in splits:
            images = ds.images(s)  # streamed: one shard's images in memory at a time
            split_rows[s] = ds.n_images(s)
            n_shards = max(1, -(-split_rows[s] // ROWS_PER_SHARD))
            for k in range(n_shards):
                chunk = list(itertools.islice(images, ROWS_PER_SHARD))
                for img in chunk:
                    counts["classes"] += len(img.classes())
                    counts["objects"] += sum(1 for a in img.annotations if not a.get("is_distractor", False))
                name = f"{s}-{k:05d}-of-{n_shards:05d}.parquet"
                shard_names.append(name)
                sources = [ds.annotation_files[s]] + [img.path for img in chunk]
                if not folder.fresh(f"{DATA}/{name}", sources):
                    def write(tmp: Path, chunk: list[DatasetImage] = chunk) -> None:
                        writer = ParquetWriter(features=feats, path=str(tmp))
                        try:
                            for img in chunk:
                                writer.write(feats.encode_example(row(img, tier)))
                                bar.advance(info=img.key)
                            writer.finalize()
                        finally:
                            writer.close()
                    folder.write_with(f"{DATA}/{name}", write)
                    folder.produced()
                else:
                    bar.advance(len(chunk))
    finally:
        bar.stop()
    folder.prune(DATA, shard_names)
    split_bytes = {s: sum((folder.root / DATA / n).stat().st_size for n in shard_names if n.startswith(f"{s}-"))
                   for s in split_rows}
    folder.write_text("README.md", dataset_card(split_rows, split_bytes, tier, counts))
    write_attribution(ds.root, folder.root, ds.scene_ids(splits))
    figures = {"rows_per_split": split_rows, "shards": len(shard_names), **counts}
    return folder.finish(ds.root, {"split": split, "caption_tier": tier}, figures)
