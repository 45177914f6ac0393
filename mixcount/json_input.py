"""Reading JSON that users hand in (side metadata files, count files): bounded, one-line failures.

``json.loads`` has two ways to fail that are not a ``ValueError``: a document nested deeper than
Python's recursion limit (``[[[[...]]]]`` 100,000 deep) raises ``RecursionError``, and a file of
gigabytes is read whole into memory before anything says a word. :func:`loads` and :func:`read` turn
both into :class:`JsonInputError`, a ``ValueError`` whose message quotes none of the text, so every
caller that already catches ``ValueError`` for malformed JSON handles them too, in one line. Numbers
past the int digit limit (``ValueError`` from the decoder) are reported the same way. ``NaN`` and
``Infinity`` (extensions Python's reader accepts) are read as ``null``: no count, size or weight is
infinite, and a record stored again as JSON stays standard JSON.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

# A side metadata file (DTC metadata.json, a plain folder's record) holds a few kB; 64 MiB is a listing
# of a million objects, and more is something else.
SIDE_FILE_BYTES = 64 * 1024 * 1024
# How deep a side file may nest: records are a few levels deep; a document nested near Python's recursion
# limit would load, and then fail where it is written again (ingest stores the record as JSON).
SIDE_FILE_DEPTH = 64
# Count files: COCO train2017's instances file is 448 MB; json holds about 5-10 times a file's size in
# memory. A larger file is better given as a text histogram (docs/scene.md, "Count targets").
COUNT_FILE_BYTES = 1024 * 1024 * 1024


class JsonInputError(ValueError):
    """JSON a user handed in cannot be used: too deep, too large, a number the decoder refuses. The
    message is a short phrase quoting none of the text (``metadata.json does not parse: <message>``)."""


def _no_constant(name: str) -> Any:
    return None  # NaN / Infinity / -Infinity: not JSON; read as null, never as a number


def _size(n: int) -> str:
    return f"{n / 1024 / 1024:,.0f} MiB" if n >= 1024 * 1024 else f"{n:,} bytes"


def loads(text: str | bytes) -> Any:
    """``json.loads`` with :class:`JsonInputError` for what it would raise besides ``JSONDecodeError``
    (that one, a ``ValueError`` too, is passed on: its message names the line and column only)."""
    try:
        return json.loads(text, parse_constant=_no_constant)
    except RecursionError:
        raise JsonInputError("nested deeper than a JSON reader follows (Python's recursion limit)") from None
    except json.JSONDecodeError:
        raise
    except UnicodeDecodeError:
        raise JsonInputError("not UTF-8 text") from None
    except JsonInputError:
        raise
    except ValueError:  # e.g. an integer past Python's 4,300-digit limit; the message would quote it
        raise JsonInputError("a number too long to read") from None


def depth(doc: Any) -> int:
    """How deep ``doc`` nests (a scalar 0, ``[]`` 1, ``[[1]]`` 2), walked without recursion."""
    deepest, todo = 0, [(doc, 1)]
    while todo:
        node, level = todo.pop()
        if isinstance(node, dict):
            deepest = max(deepest, level)
            todo.extend((v, level + 1) for v in node.values())
        elif isinstance(node, list):
            deepest = max(deepest, level)
            todo.extend((v, level + 1) for v in node)
    return deepest


def check_depth(doc: Any, max_depth: int | None) -> Any:
    """``doc``, or :class:`JsonInputError` when it nests deeper than ``max_depth`` (None: any depth)."""
    if max_depth is not None and depth(doc) > max_depth:
        raise JsonInputError(f"nested more than {max_depth} levels deep")
    return doc


def side_loads(text: str | bytes) -> Any:
    """:func:`loads` for a side file's text (a record, a listing line): at most SIDE_FILE_DEPTH deep."""
    return check_depth(loads(text), SIDE_FILE_DEPTH)


def read(path: Path, *, max_bytes: int = SIDE_FILE_BYTES, max_depth: int | None = SIDE_FILE_DEPTH) -> Any:
    """The JSON document of ``path``, refused past ``max_bytes`` before a byte of it is parsed and past
    ``max_depth`` levels after. OSError for an unreadable file, :class:`JsonInputError` /
    ``JSONDecodeError`` for unusable text."""
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size > max_bytes:
            raise JsonInputError(f"{_size(size)}, more than the {_size(max_bytes)} a file of this kind may hold")
        fh.seek(0)
        data = fh.read()
    return check_depth(loads(data), max_depth)
