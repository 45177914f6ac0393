"""The export folder: atomic writes, resume, pruning and the manifest every exporter leaves.

Resumable and idempotent: every file is written to a temporary name and renamed into place, so a file
that exists is complete. A per-sample file (image, density map, shard) is skipped when it is newer than
everything it was made from; the small index files (annotation JSON, split lists, label maps, README)
are rewritten on every run. Files in the managed folders that the current run did not produce (left by
an earlier export of other splits) are removed, so a rerun leaves exactly what a fresh run would.

``mixcount_export.json`` records the format, source dataset, options and figures of the last run; an
export folder of one format is never reused for another. The source dataset is recorded as its path
relative to the export folder (``../out``) and its ``dataset.json`` identity, never as an absolute path of
the machine that exported it (an export gets published: issue 68).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

from mixcount.atomic import atomic_path, write_bytes_atomic
from mixcount.errors import ExportError

MANIFEST = "mixcount_export.json"


def _inside(child: Path, parent: Path) -> bool:
    try:
        child.relative_to(parent)
        return True
    except ValueError:
        return False


class SpooledArray:
    """A JSON array written element by element to a temporary file, for export index files that would
    not fit in memory at the paper's scale (the masks of 4 million objects); see
    :meth:`ExportFolder.write_json_members`. ``lines=True``: JSON Lines instead (one element per line,
    no brackets; :meth:`ExportFolder.write_spooled`). Close it (or use it as a context manager) when done."""

    def __init__(self, folder: Path, *, lines: bool = False, ensure_ascii: bool = False) -> None:
        self._fh = tempfile.TemporaryFile("w+", encoding="utf-8", dir=folder)
        self.lines, self.ensure_ascii = lines, ensure_ascii
        self.n = 0

    def append(self, obj: Any) -> None:
        text = json.dumps(obj, ensure_ascii=self.ensure_ascii)
        self._fh.write(text + "\n" if self.lines else (", " if self.n else "") + text)
        self.n += 1

    def __len__(self) -> int:
        return self.n

    def copy_to(self, out: Any) -> None:
        out.write("" if self.lines else "[")
        self._fh.flush()
        self._fh.seek(0)
        shutil.copyfileobj(self._fh, out)
        self._fh.seek(0, os.SEEK_END)
        out.write("" if self.lines else "]")

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "SpooledArray":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class ExportFolder:
    """Output folder of one export (format ``fmt``) of the dataset at ``dataset_root``."""

    def __init__(self, out: Path | str, dataset_root: Path | str, fmt: str):
        self.root = Path(out).resolve()
        self.fmt = fmt
        src = Path(dataset_root).resolve()
        if _inside(self.root, src):
            raise ExportError(f"--out {out} lies inside the dataset {dataset_root}: an export never writes into "
                              "the dataset it reads; choose a folder outside it")
        if self.root.exists() and not self.root.is_dir():
            raise ExportError(f"--out {out} exists and is not a folder")
        manifest = self.root / MANIFEST
        if manifest.is_file():
            try:
                previous = json.loads(manifest.read_text(encoding="utf-8")).get("format")
            except (OSError, ValueError):
                previous = None
            if previous not in (None, fmt):
                raise ExportError(f"{out} holds a {previous!r} export; write the {fmt!r} export to another folder")
        self.root.mkdir(parents=True, exist_ok=True)
        self.written = 0
        self.skipped = 0

    def path(self, rel: str | Path) -> Path:
        p = self.root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_bytes(self, rel: str | Path, data: bytes) -> Path:
        return write_bytes_atomic(self.path(rel), data)

    def write_text(self, rel: str | Path, text: str) -> Path:
        return self.write_bytes(rel, text.encode("utf-8"))

    def write_json(self, rel: str | Path, obj: Any, indent: Optional[int] = None) -> Path:
        return self.write_text(rel, json.dumps(obj, indent=indent, ensure_ascii=False) + "\n")

    def write_json_members(self, rel: str | Path, members: Sequence[tuple[str, Any]]) -> Path:
        """Write the JSON object of ``members`` (key, value); a :class:`SpooledArray` value is copied from
        its file. The bytes are those :meth:`write_json` writes for the same object (no indent)."""
        def write(tmp: Path) -> None:
            with open(tmp, "w", encoding="utf-8") as out:
                out.write("{")
                for k, (key, value) in enumerate(members):
                    out.write((", " if k else "") + json.dumps(key, ensure_ascii=False) + ": ")
                    if isinstance(value, SpooledArray):
                        value.copy_to(out)
                    else:
                        out.write(json.dumps(value, ensure_ascii=False))
                out.write("}\n")
        return self.write_with(rel, write)

    def spool(self, *, lines: bool = False, ensure_ascii: bool = False) -> SpooledArray:
        """A :class:`SpooledArray` whose file lives in this folder (the same disk as the export)."""
        return SpooledArray(self.root, lines=lines, ensure_ascii=ensure_ascii)

    def write_spooled(self, rel: str | Path, spooled: SpooledArray) -> Path:
        """Write ``spooled`` on its own: a JSON Lines file, or a JSON array."""
        def write(tmp: Path) -> None:
            with open(tmp, "w", encoding="utf-8") as out:
                spooled.copy_to(out)
        return self.write_with(rel, write)

    def write_with(self, rel: str | Path, writer: Any) -> Path:
        """Call ``writer(tmp_path)`` and rename the result into place (for PIL, numpy, parquet writers)."""
        target = self.path(rel)
        with atomic_path(target) as tmp:
            writer(tmp)
        return target

    def copy_file(self, src: Path, rel: str | Path) -> Path:
        return self.write_with(rel, lambda tmp: shutil.copyfile(src, tmp))

    def copy_if_stale(self, src: Path, rel: str | Path) -> None:
        """Copy ``src`` to ``rel`` unless the copy there is up to date (a resumed export), counting it."""
        if not self.fresh(rel, [src]):
            self.copy_file(src, rel)
            self.produced()

    def fresh(self, rel: str | Path, sources: Iterable[Path]) -> bool:
        """True (and counted as up to date) when ``rel`` exists and is at least as new as every source."""
        target = self.root / rel
        if not target.is_file():
            return False
        mtime = target.stat().st_mtime
        if all(Path(s).stat().st_mtime <= mtime for s in sources):
            self.skipped += 1
            return True
        return False

    def produced(self, n: int = 1) -> None:
        """Count ``n`` per-sample files written by this run (the manifest reports written / up to date)."""
        self.written += n

    def prune(self, rel_dir: str, keep: Iterable[str], pattern: str = "*") -> int:
        """Delete files of ``rel_dir`` matching ``pattern`` whose names are not in ``keep``; returns how many."""
        folder = self.root / rel_dir
        if not folder.is_dir():
            return 0
        keep_set = set(keep)
        removed = 0
        for p in folder.glob(pattern):
            if p.is_file() and p.name not in keep_set:
                p.unlink()
                removed += 1
        return removed

    def finish(self, dataset_root: Path, options: dict[str, Any], figures: dict[str, Any]) -> dict[str, Any]:
        """Write the manifest; returns it."""
        from mixcount.version import __version__

        manifest = {
            "format": self.fmt, "dataset": dataset_reference(Path(dataset_root), self.root), "mixcount": __version__,
            "options": options, "figures": figures,
            "files": {"written": self.written, "up_to_date": self.skipped},
        }
        self.write_json(MANIFEST, manifest, indent=1)
        return manifest


def dataset_reference(dataset_root: Path, export_root: Path) -> dict[str, Any]:
    """How an export names the dataset it came from: ``path`` relative to the export folder, its folder
    ``name`` and the ``dataset_json_sha256`` of its ``dataset.json`` (None without one)."""
    import hashlib

    src = Path(dataset_root).resolve()
    try:
        digest: Optional[str] = hashlib.sha256((src / "dataset.json").read_bytes()).hexdigest()
    except OSError:
        digest = None
    return {"path": Path(os.path.relpath(src, Path(export_root).resolve())).as_posix(), "name": src.name,
            "dataset_json_sha256": digest}
