"""Content hashes for ingest: SHA-256 of files, streamed, combined in a stable order.

Two hashes matter for an object:

* ``content_hash``: the model file and the resources it pulls in (glTF buffers, textures, OBJ
  materials). Two objects with equal content hashes look identical; the USD asset cache is keyed by it.
* ``ingest_hash``: the content hash plus sidecars (metadata.json, licence) and the ingest settings that
  change the facts (collision budget, assumed units/up axis). Equal ingest hash = nothing to do.

Both are computed before any mesh work, so an unchanged re-ingest only reads bytes.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Iterable

CHUNK = 1 << 20


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of one file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            block = fh.read(CHUNK)
            if not block:
                break
            h.update(block)
    return h.hexdigest()


def combine(parts: Iterable[tuple[str, str]]) -> str:
    """Hash of ``(label, digest)`` pairs; the order is made canonical by sorting on the label."""
    h = hashlib.sha256()
    for label, digest in sorted(parts):
        h.update(label.encode("utf-8", "surrogateescape"))
        h.update(b"\0")
        h.update(digest.encode())
        h.update(b"\n")
    return h.hexdigest()


def files_hash(files: dict[str, Path]) -> str:
    """Combined hash of files named by a stable label (e.g. their path relative to the model)."""
    return combine((label, file_sha256(path)) for label, path in files.items())


def json_hash(value: Any) -> str:
    """Hash of a JSON-serialisable value in canonical form (sorted keys, no whitespace)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()
