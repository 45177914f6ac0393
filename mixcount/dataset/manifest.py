"""The record of a finished scene's files, and checking a scene against it (no bpy).

When a scene is finalised (just before its temporary folder is renamed into ``OUT/scenes/<scene_id>``),
:func:`record_scene_files` writes ``manifest.json`` beside its files: the size, SHA-256 and modification
time of EVERY file the folder holds at that moment (subfolders included, whatever the writer put there:
one camera or several), and a digest of that list, so a damaged manifest is noticed too.

:func:`check_scene` compares a folder with its record and reports missing, changed and extra files:

* ``deep=False`` (what ``compose`` does on every finished scene it meets): a file's size is always
  compared; its content is hashed only when its modification time differs from the record (a copy that
  did not keep times, or an edit), so a resumed run over thousands of scenes reads almost nothing;
* ``deep=True`` (``mixcount verify``): every file is hashed.

A damaged scene (a file missing or changed, or its record unreadable) is never deleted: :func:`set_aside`
renames the folder to ``OUT/scenes/.damaged/<scene_id>-<UTC time>/`` with a ``DAMAGE.json`` saying what
was wrong, and compose renders the seed again. Extra files alone do not damage a scene. A scene written
before manifests existed is "unrecorded": it is checked only for the files its ``coco.json`` and
``metadata.json`` name.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Optional

from mixcount.atomic import write_text_atomic
from mixcount.catalog.hashing import file_sha256

MANIFEST_NAME = "manifest.json"
DAMAGED_DIR = ".damaged"
DAMAGE_REPORT = "DAMAGE.json"
MANIFEST_VERSION = 1


def _walk_files(root: Path) -> Iterator[str]:
    """Every regular file under ``root`` as a posix path relative to it, sorted; the manifest left out."""
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        rel_dir = Path(dirpath).relative_to(root)
        for name in filenames:
            rel = (rel_dir / name).as_posix()
            if rel != MANIFEST_NAME:
                found.append(rel)
    yield from sorted(found)


def _files_digest(files: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(files, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def record_scene_files(scene_dir: Path) -> dict[str, Any]:
    """Write ``scene_dir/manifest.json`` recording every file now in the folder; returns the record."""
    scene_dir = Path(scene_dir)
    files: dict[str, Any] = {}
    for rel in _walk_files(scene_dir):
        path = scene_dir / rel
        st = path.stat()
        files[rel] = {"size": st.st_size, "sha256": file_sha256(path), "mtime_ns": st.st_mtime_ns}
    record = {"version": MANIFEST_VERSION, "algorithm": "sha256", "files": files, "digest": _files_digest(files)}
    write_text_atomic(scene_dir / MANIFEST_NAME, json.dumps(record, indent=1))
    return record


def read_manifest(scene_dir: Path) -> Optional[dict[str, Any]]:
    """The scene's record, None when it has none; raises ValueError when the record is damaged."""
    path = Path(scene_dir) / MANIFEST_NAME
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ValueError(f"{MANIFEST_NAME} cannot be read ({exc.strerror})") from None
    try:
        record = json.loads(text)
        files = record["files"]
        if not isinstance(files, dict) or record.get("digest") != _files_digest(files):
            raise ValueError
    except (ValueError, KeyError, TypeError):
        raise ValueError(f"{MANIFEST_NAME} is damaged (not the record mixcount wrote)") from None
    return dict(record)


def recorded_size(scene_dir: Path) -> int:
    """Total bytes of the scene's recorded files (0 without a record)."""
    try:
        record = read_manifest(scene_dir)
    except ValueError:
        return 0
    return sum(int(f.get("size", 0)) for f in (record or {}).get("files", {}).values())


@dataclass
class SceneCheck:
    """What :func:`check_scene` found in one scene folder."""

    scene_id: str
    missing: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)  # "<file> (<why>)"
    extra: list[str] = field(default_factory=list)
    unrecorded: bool = False  # written before manifests existed: only named files were checked
    error: Optional[str] = None  # the record itself is damaged or unreadable
    hashed_bytes: int = 0

    @property
    def damaged(self) -> bool:
        """A file missing or changed, or no usable record: the scene must be rendered again."""
        return bool(self.missing or self.changed or self.error)

    @property
    def ok(self) -> bool:
        return not (self.damaged or self.extra or self.unrecorded)

    def describe(self) -> str:
        """One line: ``missing rgb.png; changed coco.json (size 10 bytes, recorded 4,812)``."""
        parts = []
        if self.error:
            parts.append(self.error)
        if self.missing:
            parts.append("missing " + ", ".join(self.missing))
        if self.changed:
            parts.append("changed " + ", ".join(self.changed))
        if self.extra:
            parts.append("extra " + ", ".join(self.extra))
        if self.unrecorded and not parts:
            parts.append(f"no {MANIFEST_NAME} (written before mixcount recorded scene files): contents unproven")
        return "; ".join(parts) or "ok"

    def to_dict(self) -> dict[str, Any]:
        return {"scene_id": self.scene_id, "missing": self.missing, "changed": self.changed, "extra": self.extra,
                "unrecorded": self.unrecorded, "error": self.error, "damaged": self.damaged}


def _named_files(scene_dir: Path) -> list[str]:
    """Files a scene without a manifest names: its COCO images and metadata's ``files`` (relative to it)."""
    names: list[str] = ["metadata.json", "coco.json"]
    try:
        meta = json.loads((scene_dir / "metadata.json").read_text())
        names += [v for v in (meta.get("files") or {}).values() if isinstance(v, str)]
        names += [e["file"] for e in meta.get("exemplars") or [] if isinstance(e, dict) and isinstance(e.get("file"), str)]
    except (OSError, ValueError, AttributeError):
        pass
    try:
        coco = json.loads((scene_dir / "coco.json").read_text())
        prefix = f"scenes/{scene_dir.name}/"
        for img in coco.get("images") or []:
            name = str(img.get("file_name", ""))
            if name.startswith(prefix):
                names.append(name[len(prefix):])
    except (OSError, ValueError, AttributeError):
        pass
    return list(dict.fromkeys(names))


def check_scene(scene_dir: Path, *, deep: bool, hash_changed_times: bool = True) -> SceneCheck:
    """Compare ``scene_dir`` with its ``manifest.json`` (see the module docstring for ``deep``;
    ``hash_changed_times=False``: sizes only, nothing is read - what ``merge`` checks)."""
    scene_dir = Path(scene_dir)
    check = SceneCheck(scene_dir.name)
    try:
        record = read_manifest(scene_dir)
    except ValueError as exc:
        check.error = str(exc)
        return check
    present = set(_walk_files(scene_dir))
    if record is None:
        check.unrecorded = True
        check.missing = [n for n in _named_files(scene_dir) if n not in present]
        return check
    files: dict[str, Any] = record["files"]
    for rel, want in files.items():
        path = scene_dir / rel
        try:
            st = path.stat()
        except FileNotFoundError:
            check.missing.append(rel)
            continue
        except OSError as exc:
            check.changed.append(f"{rel} (cannot be read: {exc.strerror})")
            continue
        if st.st_size != int(want["size"]):
            check.changed.append(f"{rel} (size {st.st_size:,} bytes, recorded {int(want['size']):,})")
            continue
        if deep or (hash_changed_times and st.st_mtime_ns != want.get("mtime_ns")):
            try:
                digest = file_sha256(path)
            except OSError as exc:
                check.changed.append(f"{rel} (cannot be read: {exc.strerror})")
                continue
            check.hashed_bytes += st.st_size
            if digest != want["sha256"]:
                check.changed.append(f"{rel} (content differs from its record)")
    check.extra = sorted(present - set(files))
    return check


def is_finished(scene_dir: Path) -> bool:
    """A folder a finished scene wrote: it has a record, or a ``metadata.json`` that says complete.
    (A record without a complete metadata.json is a damaged finished scene, not an unfinished one.)"""
    from mixcount.dataset.scene_writer import is_complete

    return (Path(scene_dir) / MANIFEST_NAME).exists() or is_complete(scene_dir)


def set_aside(scene_dir: Path, check: SceneCheck) -> Optional[Path]:
    """Rename a damaged scene folder to ``scenes/.damaged/<scene_id>-<UTC time>/`` and write what was
    wrong into its ``DAMAGE.json``. Returns the new path; None when the folder is already gone (another
    run set it aside first)."""
    scene_dir = Path(scene_dir)
    dest_root = scene_dir.parent / DAMAGED_DIR
    dest_root.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for k in range(1000):
        dest = dest_root / (f"{scene_dir.name}-{stamp}" + (f"-{k}" if k else ""))
        if dest.exists():
            continue
        try:
            os.rename(scene_dir, dest)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
                continue
            raise
        break
    else:  # pragma: no cover - a thousand set-asides of one scene in one second
        raise OSError(errno.EEXIST, "no free name under", str(dest_root))
    report = {"scene_id": scene_dir.name, "set_aside_at": stamp, "from": str(scene_dir), **check.to_dict()}
    try:
        (dest / DAMAGE_REPORT).write_text(json.dumps(report, indent=1))
    except OSError:
        pass  # the folder itself is the trace; the report is a courtesy (the disk may be full)
    return dest


def merge_problem(scene_dir: Path) -> Optional[str]:
    """Why a scene must be left out of a merge (a recorded file missing or of another size, or its
    record damaged), or None. Cheap: one stat per file, nothing read."""
    check = check_scene(scene_dir, deep=False, hash_changed_times=False)
    return check.describe() if check.damaged else None


def finished_but_unlisted(scenes_dir: Path, listed: set[str]) -> list[str]:
    """Finished scene folders (with a record) missing from ``listed``: a merge that could not read their
    ``metadata.json`` names them instead of leaving them out in silence."""
    out: list[str] = []
    if not Path(scenes_dir).is_dir():
        return out
    for entry in sorted(os.scandir(scenes_dir), key=lambda e: e.name):
        if entry.is_dir() and not entry.name.startswith(".") and entry.name not in listed:
            if (Path(entry.path) / MANIFEST_NAME).exists():
                check = check_scene(Path(entry.path), deep=False, hash_changed_times=False)
                why = check.describe() if check.damaged else "metadata.json is not a finished scene's"
                out.append(f"{entry.name}: {why}")
    return out
