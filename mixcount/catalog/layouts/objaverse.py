"""Objaverse / Amazon Berkeley Objects (``objaverse``): trees of model files named by an id (uid,
``3dmodel_id``), described by side metadata files (JSON mapping or list, JSONL, CSV; ``.gz`` too) in the
folders above the model, in ``metadata/`` or ``annotations/`` beside them (Objaverse's ``glbs/`` +
``metadata/``), or given with ``--metadata`` (ABO's ``listings/metadata/*.json.gz``). A model whose file
stem is an id in those files takes its name, category and licence from the record.

A file-level layout: the walker asks :func:`read_file` about each model file of a folder that no folder
layout claimed, before the plain-folder reading (:mod:`mixcount.catalog.layouts.folder`)."""

from __future__ import annotations

import csv
import gzip
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional

import mixcount.json_input as json_input
from mixcount.catalog.layouts.candidates import (
    SOURCE_OBJAVERSE,
    Candidate,
    Walker,
    apply_identity,
    ignored_entries,
    model_files_in,
    record_identity,
    scan_folder,
)
from mixcount.catalog.naming import category_from_stem, safe_text
from mixcount.errors import CatalogError
from mixcount.library_root import refusal

NAME = SOURCE_OBJAVERSE
SIDE_SUFFIXES = (".json", ".jsonl", ".csv", ".json.gz", ".jsonl.gz", ".csv.gz")
SIDE_FOLDERS = ("metadata", "annotations")
ID_FIELDS = ("uid", "id", "object_id", "model_id", "3dmodel_id", "item_id", "sha256", "file_identifier", "asset_id")


def read_file(ctx: Walker, path: Path) -> Optional[Candidate]:
    """The Objaverse object a model file is: its side-metadata record's identity (forced ``objaverse``:
    every model file, with or without a record); None when the file is no Objaverse object."""
    found = ctx.side.lookup(path.stem, path.parent, ctx.root) if ctx.layout in ("auto", "objaverse") else None
    if found is None and ctx.layout != "objaverse":
        return None
    stem = safe_text(path.stem)
    cand = Candidate(SOURCE_OBJAVERSE, stem, stem, category_from_stem(stem, path.parent.name), path,
                     layout=SOURCE_OBJAVERSE)
    if found is None:
        cand.metadata = {"record": None}
        return cand
    rec, side_file = found
    ident = record_identity(rec)
    cand.metadata = {"record": rec, "metadata_file": str(side_file)}
    apply_identity(cand, ident)
    cand.ignored.extend(ignored_entries(rec, side_file.name))
    cand.license = ident["license"]
    return cand


class SideMetadata:
    """Records of JSON / JSONL / CSV side files, indexed by every id-like field (and mapping key).

    Files are read once, when a model first needs them; a file that does not parse as records is
    skipped (it is not side metadata). ``explicit`` files are searched for every model."""

    def __init__(self, explicit: Iterable[Path] = ()) -> None:
        self._loaded: dict[Path, dict[str, dict[str, Any]]] = {}
        self._dir_files: dict[Path, list[Path]] = {}
        self._side_dirs: dict[Path, list[Path]] = {}
        self.explicit = [Path(p).expanduser().resolve() for p in explicit]
        for p in self.explicit:
            if not p.is_file():
                raise CatalogError(f"metadata file not found: {p}")
            if not self._index(p):
                raise CatalogError(f"metadata file {p} holds no records (JSON object or list, JSONL or CSV "
                                   "with an id column such as uid)")

    @staticmethod
    def _records(path: Path) -> Iterator[tuple[str | None, dict[str, Any]]]:
        name = path.name.lower()
        opener = gzip.open if name.endswith(".gz") else open
        base = name[:-3] if name.endswith(".gz") else name
        with opener(path, "rt", encoding="utf-8", errors="replace", newline="") as fh:  # type: ignore[operator]
            if base.endswith(".csv"):
                for row in csv.DictReader(fh):
                    yield None, {k.strip(): v for k, v in row.items() if k}
                return
            text = fh.read()
        try:
            data = None if base.endswith(".jsonl") else json_input.side_loads(text)  # too deep: a ValueError
        except ValueError:
            data = None  # ABO names its JSON-lines listings *.json.gz
        if data is None:
            for line in text.splitlines():
                line = line.strip()
                if line:
                    rec = json_input.side_loads(line)
                    if isinstance(rec, dict):
                        yield None, rec
            return
        if isinstance(data, list):
            for rec in data:
                if isinstance(rec, dict):
                    yield None, rec
        elif isinstance(data, dict) and data and all(isinstance(v, dict) for v in data.values()):
            for key, rec in data.items():
                yield str(key), rec

    def _index(self, path: Path) -> dict[str, dict[str, Any]]:
        if path in self._loaded:
            return self._loaded[path]
        index: dict[str, dict[str, Any]] = {}
        try:
            for key, rec in self._records(path):
                keys = {key} if key else set()
                for f in ID_FIELDS:
                    v = rec.get(f)
                    if isinstance(v, (str, int)) and not isinstance(v, bool) and str(v).strip():
                        keys.add(str(v).strip())
                for f in ("path", "file", "filename", "glb", "model"):
                    v = rec.get(f)
                    if isinstance(v, str) and v.strip():
                        keys.add(Path(v.strip()).stem)
                for k in keys:
                    index.setdefault(k, rec)
        except (OSError, ValueError, UnicodeDecodeError, csv.Error, EOFError):
            index = {}
        self._loaded[path] = index
        return index

    def _side_files(self, folder: Path) -> list[Path]:
        if folder not in self._dir_files:
            files = []
            try:
                for e in scan_folder(folder):
                    if e.name.startswith(".") or e.name == "metadata.json" and _has_single_model(folder):
                        continue
                    if e.name.lower().endswith(SIDE_SUFFIXES) and e.is_file():
                        files.append(Path(e.path))
            except OSError:
                pass
            self._dir_files[folder] = files
        return self._dir_files[folder]

    def _with_side_folders(self, folder: Path) -> list[Path]:
        if folder not in self._side_dirs:
            self._side_dirs[folder] = [folder] + [folder / n for n in SIDE_FOLDERS if (folder / n).is_dir()
                                                  and not refusal(folder / n, f"side metadata folder {n}/")]
        return self._side_dirs[folder]

    def lookup(self, uid: str, folder: Path, root: Path) -> tuple[dict[str, Any], Path] | None:
        """The record for ``uid`` from files in ``folder`` and above (up to ``root``), in a ``metadata/``
        or ``annotations/`` folder beside any of those, or in the explicit files; with its file."""
        dirs = []
        cur = folder
        while True:
            dirs.append(cur)
            if cur == root or cur.parent == cur or root not in cur.parents:
                break
            cur = cur.parent
        files = list(self.explicit) + [f for d in dirs for side in self._with_side_folders(d) for f in self._side_files(side)]
        for path in files:
            rec = self._index(path).get(uid)
            if rec is not None:
                return rec, path
        return None


def _has_single_model(folder: Path) -> bool:
    try:
        return len(model_files_in(scan_folder(folder))) == 1
    except OSError:
        return False
