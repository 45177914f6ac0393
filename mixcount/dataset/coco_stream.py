"""Read a large JSON object file (a merged COCO file) one top-level member, or one array element, at a time.

At the paper's scale the merged ``instances_<split>.json`` holds ~4 million annotations with their RLE
masks: 3.4 GB for 58,000 scenes at 1024² (docs/performance.md, merge). ``json.loads`` of such a file
needs the text and every parsed mask in memory at once (~0.25 GB per 1,000 scenes, so ~14 GB at 58k).
:func:`members` walks the file with a small buffer instead and hands each element of the arrays it is
told to stream to the caller as soon as it is parsed, so an exporter can hold one image's annotations
at a time. Values are parsed by the standard library's decoder, so what it yields is exactly what
``json.loads`` would give.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Collection, Iterator, TextIO

CHUNK_CHARS = 1 << 22  # characters read at a time
MAX_VALUE_CHARS = 1 << 28  # a single streamed element (or other member) larger than this is an error
_WS = re.compile(r"[ \t\n\r]*")
_DECODER = json.JSONDecoder()


class _Scanner:
    """A read buffer over ``fh`` with the decoder's ``raw_decode`` on top; grows only to hold one value."""

    def __init__(self, fh: TextIO, chunk: int) -> None:
        self.fh, self.chunk = fh, chunk
        self.buf, self.pos, self.eof = "", 0, False

    def _more(self) -> bool:
        if self.eof:
            return False
        data = self.fh.read(self.chunk)
        if not data:
            self.eof = True
            return False
        self.buf = self.buf[self.pos:] + data
        self.pos = 0
        return True

    def peek(self) -> str:
        """The next character that is not white space ("" at the end of the file)."""
        while True:
            self.pos = _WS.match(self.buf, self.pos).end()  # type: ignore[union-attr]
            if self.pos < len(self.buf):
                return self.buf[self.pos]
            if not self._more():
                return ""

    def expect(self, char: str) -> None:
        got = self.peek()
        if got != char:
            raise ValueError(f"expected {char!r} at character {self.pos}, found {got or 'the end of the file'!r}")
        self.pos += 1

    def next_item(self, close: str) -> bool:
        """After a member or element: True past a comma (another follows), False past ``close``."""
        if self.peek() == ",":
            self.pos += 1
            return True
        self.expect(close)
        return False

    def value(self) -> Any:
        """The next JSON value, read further into the file until it is complete."""
        self.peek()
        while True:
            try:
                value, end = _DECODER.raw_decode(self.buf, self.pos)
            except json.JSONDecodeError:
                if len(self.buf) - self.pos > MAX_VALUE_CHARS or not self._more():
                    raise
                continue
            # a number or literal that ends with the buffer may go on in the next chunk
            if end == len(self.buf) and self.buf[self.pos] not in '{["' and self._more():
                continue
            self.pos = end
            return value


def members(path: Path | str, streamed: Collection[str] = (), *,
            chunk: int = CHUNK_CHARS) -> Iterator[tuple[str, Any, bool]]:
    """The top-level members of the JSON object in ``path``, in file order, as (key, value, False).

    For a key in ``streamed`` whose value is a non-empty array, each element comes as (key, element,
    True) instead, parsed only when the caller asks for it; the array itself is never held. Raises
    ``ValueError`` (``json.JSONDecodeError`` included) on a file that is not one JSON object."""
    with open(path, encoding="utf-8") as fh:
        sc = _Scanner(fh, chunk)
        sc.expect("{")
        if sc.peek() == "}":
            return
        while True:
            key = sc.value()
            if not isinstance(key, str):
                raise ValueError(f"object key expected at character {sc.pos}")
            sc.expect(":")
            if key in streamed and sc.peek() == "[":
                sc.pos += 1
                if sc.peek() == "]":  # an empty array comes whole
                    sc.pos += 1
                    yield key, [], False
                else:
                    while True:
                        yield key, sc.value(), True
                        if not sc.next_item("]"):
                            break
            else:
                yield key, sc.value(), False
            if not sc.next_item("}"):
                break
        if sc.peek():
            raise ValueError(f"extra data after the JSON object at character {sc.pos}")
