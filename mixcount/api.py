"""The Python API: the main jobs without the CLI (``import mixcount``; README "Python API").

- :func:`open_catalog` - the catalog (SQLite) the CLI's ``--db`` names;
- :func:`compose` - sample, stage and render scenes into a dataset folder (``mixcount compose``);
- :func:`package` - copy the assets the stages use into the dataset (``mixcount package``);
- :func:`load_dataset` - a composed dataset as :class:`Dataset`, whose :class:`Sample` s hold the image,
  boxes, masks, points, counts, captions and exemplars as numpy arrays and PIL images.

Reading a dataset imports neither bpy nor pxr; only :func:`compose` starts Blender (in worker processes).
The readers are the ones the exporters use (:mod:`mixcount.export.reader`) and the stored passes load
through :func:`mixcount.dataset.read_depth` / :func:`~mixcount.dataset.read_normals`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # the API's return types, imported lazily at run time (import mixcount stays light)
    from mixcount.catalog.db import Catalog
    from mixcount.dataset.package import PackageReport
    from mixcount.run.compose import ComposeSummary

from mixcount.scene.spec import TIERS as CAPTION_TIERS  # the one caption-tier tuple


def open_catalog(db: str | Path, *, data_dir: Optional[str] = None) -> "Catalog":
    """Open (creating and migrating when needed) the catalog at ``db`` (a SQLite path or SQLAlchemy URL);
    ``data_dir`` as ``catalog.data_dir`` (None: configs/default.toml's, "" = beside the SQLite file). Close
    it with ``.close()``."""
    from mixcount.catalog.db import open_catalog as _open

    if data_dir is None:
        from mixcount.config import load_config

        data_dir = load_config().catalog.data_dir
    return _open(str(db), data_dir=data_dir)


def compose(catalog: "Catalog", out: str | Path, *, n: int, split: Optional[str] = None, seed: Optional[int] = None,
            config: Sequence[str | Path] = (), overrides: Sequence[str] = (), resolution: Optional[int] = None,
            samples: Optional[int] = None, package_assets: bool = False, progress: bool = False) -> "ComposeSummary":
    """Render until ``n`` scenes of ``split`` are complete in ``out`` and merge them, as ``mixcount compose``
    does; returns its summary (``written``, ``failed``, ``outputs`` ...). ``config``: files or names layered
    over configs/default.toml (``"quick"``); ``overrides``: ``"section.key=value"`` strings like ``--set``.
    ``package_assets`` copies the assets into ``out/assets/`` at the end (:func:`package`). The checks, the
    pool loading and the run are the CLI's own (:class:`mixcount.run.compose_entry.ComposeJob`): a bad count
    target or an empty split is a one-line error before anything is written."""
    from mixcount.config import load_config
    from mixcount.run.compose_entry import ComposeJob

    cfg = load_config(list(config), list(overrides), values={k: v for k, v in {
        "compose.split": split, "compose.seed": seed, "compose.resolution": resolution,
        "compose.samples": samples}.items() if v is not None})
    out = Path(out).resolve()
    summary = ComposeJob.checked(cfg, n=n, out_dir=out).run(catalog, progress=progress)
    if package_assets:  # each asset checked against the catalog's libraries: one from outside is an error
        from mixcount.dataset.package import package_with_catalog

        package_with_catalog(out, catalog, cfg).raise_if_refused(out)
    return summary


def package(out: str | Path, *, search: Sequence[str | Path] = (), catalog: Optional["Catalog"] = None) -> "PackageReport":
    """Copy every file the dataset's stages use into ``out/assets/`` (``mixcount package``); returns the
    report (``copied``, ``bytes``, ``refused`` ...). ``search``: folders to find assets whose links are broken,
    before ``$MIXCOUNT_ASSETS``. ``catalog``: the catalog that made the dataset; each asset is then checked
    against its libraries first and one from outside them is refused (not copied, ``refused``); without it
    nothing is checked."""
    from mixcount.dataset.package import package_assets, package_with_catalog

    if catalog is not None:
        from mixcount.config import load_config

        return package_with_catalog(Path(out), catalog, load_config(), search=[Path(s) for s in search])
    return package_assets(Path(out), search=[Path(s) for s in search])


def load_dataset(root: str | Path) -> "Dataset":
    """A composed dataset folder (``mixcount compose --out``) for reading."""
    return Dataset(Path(root))


@dataclass(frozen=True)
class Exemplar:
    """One exemplar crop: ``kind`` "internal" (this image), "cross_scene" (the same object in another scene
    of the split) or "canonical" (the catalog's white-background render); ``file`` relative to the dataset."""

    kind: str
    category_id: int
    file: str
    root: Path = field(repr=False)
    scene_id: Optional[str] = None
    exemplar_score: Optional[float] = None
    bbox: Optional[tuple[float, float, float, float]] = None  # in its source image (internal, cross-scene)

    def image(self) -> Any:
        """The crop as a PIL image (RGB)."""
        from PIL import Image

        with Image.open(self.root / self.file) as im:
            return im.convert("RGB")


@dataclass(frozen=True)
class Sample:
    """One image of the dataset (one scene and camera) with its annotations, every array in pixel units.

    ``boxes`` (N, 4) COCO [x, y, w, h]; ``points`` (N, 2) [x, y] pixel centres on each object; ``category_ids``
    and ``is_distractor`` (N,); ``counts`` category id -> counted objects; ``captions`` category id ->
    {short, concise, detailed} of the classes counted here; ``exemplars`` category id -> its internal,
    cross-scene and canonical :class:`Exemplar` s."""

    split: str
    scene_id: str
    image_id: int
    file: Path
    width: int
    height: int
    annotations: tuple[Mapping[str, Any], ...] = field(repr=False)
    boxes: NDArray[Any] = field(repr=False)
    points: NDArray[Any] = field(repr=False)
    category_ids: NDArray[Any] = field(repr=False)
    is_distractor: NDArray[Any] = field(repr=False)
    counts: Mapping[int, int] = field(default_factory=dict)
    captions: Mapping[int, Mapping[str, str]] = field(default_factory=dict)
    exemplars: Mapping[int, tuple[Exemplar, ...]] = field(default_factory=dict, repr=False)

    def image(self) -> Any:
        """The render as a PIL image (RGB)."""
        from PIL import Image

        with Image.open(self.file) as im:
            return im.convert("RGB")

    def masks(self) -> NDArray[Any]:
        """Visible instance masks, bool (N, H, W), in ``annotations`` order (decoded from the COCO RLE)."""
        from pycocotools import mask as mask_utils

        if not self.annotations:
            return np.zeros((0, self.height, self.width), dtype=bool)
        return np.stack([mask_utils.decode(dict(a["segmentation"])).astype(bool) for a in self.annotations])

    def depth(self) -> NDArray[Any]:
        """The scene's stored depth pass (metres, float32 (H, W); 0 = no surface) of this camera."""
        from mixcount.dataset import read_depth

        return read_depth(self._pass_file("depth"))

    def normals(self) -> NDArray[Any]:
        """The scene's stored normal pass (camera space, float32 (H, W, 3)) of this camera."""
        from mixcount.dataset import read_normals

        return read_normals(self._pass_file("normal"))

    def _pass_file(self, name: str) -> Path:
        stem = self.file.stem  # rgb or rgb_cam_<k>
        suffix = stem[len("rgb"):]
        found = sorted(self.file.parent.glob(f"{name}{suffix}.*"))
        if not found:
            raise FileNotFoundError(f"{self.file.parent}: no {name}{suffix} pass stored (compose --passes)")
        return found[0]


class Dataset:
    """A composed dataset: splits and their :class:`Sample` s, read from the merged COCO files."""

    def __init__(self, root: Path) -> None:
        from mixcount.export.reader import ComposedDataset

        self.root = Path(root)
        self._reader = ComposedDataset(self.root)

    @property
    def splits(self) -> list[str]:
        return list(self._reader.splits)

    @functools.cached_property
    def info(self) -> dict[str, Any]:
        """``dataset.json`` (counts per split, config, run)."""
        import json

        return dict(json.loads((self.root / "dataset.json").read_text()))

    def __len__(self) -> int:
        return sum(self._reader.n_images(s) for s in self.splits)

    def samples(self, split: Optional[str] = None) -> Iterator[Sample]:
        """Every image of ``split`` (all splits when None), in image-id order."""
        for s in self._reader.select_splits(split):
            for img in self._reader.images(s):
                yield self._sample(s, img)

    def _sample(self, split: str, img: Any) -> Sample:
        from mixcount.export.object_points import object_point

        anns = tuple(img.annotations)
        boxes = np.array([[float(v) for v in a["bbox"]] for a in anns], dtype=np.float64).reshape(-1, 4)
        points = np.array([object_point(a) for a in anns], dtype=np.float64).reshape(-1, 2)
        classes = img.classes()
        exemplars = {cid: self._exemplars(img, cid) for cid in classes}
        return Sample(split=split, scene_id=img.scene_id, image_id=img.id, file=img.path, width=img.width,
                      height=img.height, annotations=anns, boxes=boxes, points=points,
                      category_ids=np.array([int(a["category_id"]) for a in anns], dtype=np.int64),
                      is_distractor=np.array([bool(a.get("is_distractor", False)) for a in anns], dtype=bool),
                      counts={cid: img.count(cid) for cid in classes},
                      captions={cid: {t: str(img.categories[cid].get(t) or "") for t in CAPTION_TIERS} for cid in classes},
                      exemplars=exemplars)

    def _exemplars(self, img: Any, cid: int) -> tuple[Exemplar, ...]:
        out = []
        from mixcount.dataset.external_exemplars import crop_name

        ranked = img.exemplar_ranking(cid)
        crops = next((e.get("crops") for e in img.record.get("exemplars", []) if int(e["category_id"]) == cid), None)
        crops = crops or [crop_name(img.record, cid, r) for r in range(len(ranked))]  # scenes before "crops"
        for a, crop in zip(ranked, crops):
            out.append(Exemplar("internal", cid, str(crop), self.root, img.scene_id, float(a.get("exemplar_score", 0.0)),
                                tuple(float(v) for v in a["bbox"])))  # type: ignore[arg-type]
        for c in img.cross_scene_exemplars(cid):
            out.append(Exemplar("cross_scene", cid, str(c["crop"]), self.root, str(c["scene_id"]),
                                float(c["exemplar_score"]), tuple(float(v) for v in c["bbox"])))  # type: ignore[arg-type]
        canonical = img.categories[cid].get("external_exemplar")
        if canonical:
            out.append(Exemplar("canonical", cid, str(canonical), self.root))
        return tuple(out)
