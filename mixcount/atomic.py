"""Atomic file writes: write beside the target under a temporary name, then ``os.replace`` it into place.

A reader (or a process killed mid-write) never sees half a file: the target is either the old file or the
whole new one. The temporary name is ``.<name>.<pid>.<random>.tmp<suffix>`` in the target's folder (the
same file system, so the rename is atomic); it keeps the target's suffix, because writers such as PIL,
trimesh, pymeshlab and bpy choose the format by extension, and it holds the pid and a random part, so
concurrent writers of one target never share a temporary file. A failed write removes its temporary file.
"""

from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


def temp_beside(path: Path | str) -> Path:
    """A fresh temporary name in ``path``'s folder, with ``path``'s suffix."""
    p = Path(path)
    return p.with_name(f".{p.stem}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{p.suffix}")


@contextmanager
def atomic_path(path: Path | str) -> Iterator[Path]:
    """``with atomic_path(target) as tmp: write(tmp)``: on success ``tmp`` replaces ``target``; on an
    exception the temporary file is removed and ``target`` is left as it was."""
    target = Path(path)
    tmp = temp_beside(target)
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes_atomic(path: Path | str, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: Path | str, text: str) -> Path:
    """``text`` as UTF-8, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
