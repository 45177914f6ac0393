"""``mixcount verify OUT``: prove a dataset whole, or say exactly what is not (no bpy).

Two checks, one pass each:

1. every finished scene folder against its record (``manifest.json``, :mod:`mixcount.dataset.manifest`):
   missing, changed (size, or SHA-256 of the content) and extra files; a record that is damaged; a
   scene written before records existed ("unrecorded": only the files it names are checked);
2. the merged files against the scenes: each ``annotations/instances_<split>.json`` must hold exactly
   the sound finished scenes of its split, each with as many images and annotations as its own
   ``coco.json``, and only image files that exist; ``dataset.json`` must list exactly those scenes;
   every ``external_exemplar`` a category names must exist.

The merged COCO files are streamed (:mod:`mixcount.dataset.coco_stream`), so memory holds a few
counters per scene, never the merged annotations. ``deep=False`` (``--quick``) checks sizes, and hashes
only files whose modification time changed, as ``compose`` does when it resumes.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from mixcount.dataset.manifest import SceneCheck, check_scene, is_finished
from mixcount.progress import ProgressReporter, as_reporter


@dataclass
class VerifyReport:
    out_dir: str
    scenes: int = 0  # finished scene folders checked
    sound: int = 0
    unfinished: list[str] = field(default_factory=list)  # folders no finished scene wrote (stage-only, ...)
    scene_problems: list[SceneCheck] = field(default_factory=list)
    merged_problems: list[str] = field(default_factory=list)
    hashed_bytes: int = 0
    seconds: float = 0.0

    @property
    def problems(self) -> int:
        return len(self.scene_problems) + len(self.merged_problems)

    def lines(self, limit: Optional[int] = None) -> list[str]:
        """One line per problem: ``scene_000003: missing rgb.png`` / ``annotations/...: ...``."""
        out = [f"{c.scene_id}: {c.describe()}" for c in self.scene_problems] + list(self.merged_problems)
        if limit is not None and len(out) > limit:
            out = out[:limit] + [f"... and {len(out) - limit} more (the JSON report lists all)"]
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"out_dir": self.out_dir, "scenes": self.scenes, "sound": self.sound, "problems": self.problems,
                "damaged": sum(c.damaged for c in self.scene_problems),
                "scene_problems": [c.to_dict() for c in self.scene_problems],
                "merged_problems": self.merged_problems, "unfinished": self.unfinished,
                "hashed_bytes": self.hashed_bytes, "seconds": self.seconds}


@dataclass
class _SceneShape:
    split: Optional[str]
    images: int
    annotations: int


def _scene_shape(scene_dir: Path) -> Optional[_SceneShape]:
    try:
        meta = json.loads((scene_dir / "metadata.json").read_text())
        coco = json.loads((scene_dir / "coco.json").read_text())
        return _SceneShape(meta.get("split"), len(coco["images"]), len(coco["annotations"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _scene_of(image: dict[str, Any]) -> Optional[str]:
    sid = image.get("scene_id")
    if sid:
        return str(sid)
    parts = str(image.get("file_name", "")).split("/")
    return parts[1] if len(parts) >= 3 and parts[0] == "scenes" else None


def _check_split_file(out_dir: Path, path: Path, split: str, shapes: dict[str, _SceneShape],
                      problems: list[str]) -> set[str]:
    """Stream one merged COCO file; append its problems; return the scene ids it holds."""
    from mixcount.dataset.coco_stream import members

    rel = path.relative_to(out_dir).as_posix()
    images: dict[str, int] = {}
    annotations: dict[str, int] = {}
    missing_files: list[str] = []
    missing_exemplars: list[str] = []
    try:
        for key, value, _streamed in members(path, ("images", "annotations", "categories")):
            if key == "images" and isinstance(value, dict):
                sid = _scene_of(value) or "?"
                images[sid] = images.get(sid, 0) + 1
                name = str(value.get("file_name", ""))
                if not name or not (out_dir / name).is_file():
                    missing_files.append(name or "(no file_name)")
            elif key == "annotations" and isinstance(value, dict):
                sid = str(value.get("scene_id", "?"))
                annotations[sid] = annotations.get(sid, 0) + 1
            elif key == "categories" and isinstance(value, dict):
                ext = value.get("external_exemplar")
                if ext and not (out_dir / str(ext)).is_file():
                    missing_exemplars.append(str(ext))
    except (OSError, ValueError) as exc:
        problems.append(f"{rel}: cannot be read as COCO ({type(exc).__name__}: {str(exc)[:200]}); "
                        "run `mixcount merge` again")
        return set()
    for name in missing_files[:20]:
        problems.append(f"{rel}: lists image {name}, which does not exist")
    if len(missing_files) > 20:
        problems.append(f"{rel}: ... and {len(missing_files) - 20} more images that do not exist")
    for ext in sorted(set(missing_exemplars)):
        problems.append(f"{rel}: a category names external exemplar {ext}, which does not exist")
    held = set(images) | set(annotations)
    for sid in sorted(held):
        shape = shapes.get(sid)
        if shape is None or shape.split != split:
            problems.append(f"{rel}: holds scene {sid}, which is not a sound finished scene of split {split}")
        elif (images.get(sid, 0), annotations.get(sid, 0)) != (shape.images, shape.annotations):
            problems.append(f"{rel}: scene {sid} has {images.get(sid, 0)} image(s) and {annotations.get(sid, 0)} "
                            f"annotation(s) there, {shape.images} and {shape.annotations} in its coco.json")
    for sid in sorted(s for s, shape in shapes.items() if shape.split == split and s not in held):
        problems.append(f"{rel}: lacks finished scene {sid} (run `mixcount merge`)")
    return held


def _dataset_scene_ids(path: Path) -> Optional[set[str]]:
    from mixcount.dataset.coco_stream import members

    ids: set[str] = set()
    for key, value, streamed in members(path, ("scenes",)):
        if key == "scenes" and streamed and isinstance(value, dict):
            ids.add(str(value.get("scene_id")))
    return ids


def verify_dataset(out_dir: Path, *, deep: bool = True,
                   progress: ProgressReporter | bool | None = None) -> VerifyReport:
    """Check every scene of ``out_dir`` and the merged files (see the module docstring)."""
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    report = VerifyReport(out_dir=str(out_dir))
    scenes_dir = out_dir / "scenes"
    names = sorted(p.name for p in scenes_dir.iterdir() if p.is_dir() and not p.name.startswith(".")) \
        if scenes_dir.is_dir() else []
    ann_dir = out_dir / "annotations"
    split_files = sorted(ann_dir.glob("instances_*.json")) if ann_dir.is_dir() else []
    bar = as_reporter(progress)
    bar.start("verify", len(names) + len(split_files) + 1)
    shapes: dict[str, _SceneShape] = {}
    try:
        for name in names:
            d = scenes_dir / name
            if not is_finished(d):
                report.unfinished.append(name)
            else:
                report.scenes += 1
                check = check_scene(d, deep=deep)
                report.hashed_bytes += check.hashed_bytes
                if not check.ok:
                    report.scene_problems.append(check)
                shape = None if check.damaged else _scene_shape(d)
                if shape is not None:
                    shapes[name] = shape
                    report.sound += 1 if check.ok else 0
                elif not check.damaged:
                    check.error = "metadata.json or coco.json cannot be read"
                    if check not in report.scene_problems:
                        report.scene_problems.append(check)
            bar.advance(1, info=f"{len(report.scene_problems)} with problems")
        merged: set[str] = set()
        splits_seen = set()
        for path in split_files:
            split = path.stem[len("instances_"):]
            splits_seen.add(split)
            merged |= _check_split_file(out_dir, path, split, shapes, report.merged_problems)
            bar.advance(1)
        for split in sorted({s.split for s in shapes.values() if s.split is not None} - splits_seen):
            report.merged_problems.append(f"annotations/instances_{split}.json is missing: the split's finished "
                                          "scenes are not merged (run `mixcount merge`)")
        dataset = out_dir / "dataset.json"
        if shapes and not dataset.is_file():
            report.merged_problems.append("dataset.json is missing (run `mixcount merge`)")
        elif dataset.is_file():
            try:
                listed = _dataset_scene_ids(dataset) or set()
            except (OSError, ValueError) as exc:
                report.merged_problems.append(f"dataset.json cannot be read ({type(exc).__name__}); run `mixcount merge`")
            else:
                extra, lacking = sorted(listed - set(shapes)), sorted(set(shapes) - listed)
                if extra:
                    report.merged_problems.append(f"dataset.json lists {len(extra)} scene(s) that are not sound "
                                                  f"finished scenes: {', '.join(extra[:10])}")
                if lacking:
                    report.merged_problems.append(f"dataset.json lacks {len(lacking)} finished scene(s): "
                                                  f"{', '.join(lacking[:10])} (run `mixcount merge`)")
        bar.advance(1)
    finally:
        bar.stop()
    report.seconds = round(time.perf_counter() - t0, 3)
    return report
