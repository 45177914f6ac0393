"""Keeping the captioner's API key out of every text mixcount writes (stderr, logs, the database).

A server may echo the key back in any form: as sent, in lower or upper case, URL-encoded (``%2D``),
JSON-escaped (``\\u0073k-...``, ``\\/``), as an HTML entity, base64 (an ``Authorization: Basic`` header,
a token it minted around it), hex, or only a part of it (a message cut at 300 characters). Matching the
exact key misses all of these, so :class:`Redactor` reads a text the way each of them writes it:

* each encoded character (``%XX``, ``\\uXXXX``, ``\\/``, ``&#NN;``, ``&#xNN;``, also escaped again:
  ``%252D``, ``\\\\u0073``, ``&amp;#115;``) is decoded and the
  result case-folded, and every run of at least ``run`` characters that is also a run of the case-folded
  key is marked;
* base64 of the key at each of the three byte alignments (standard and URL-safe alphabet), and its hex
  form, are searched the same way in the raw text;

and each marked stretch of the raw text becomes ``[redacted]``. ``run`` is 8 characters (the whole key
when it is shorter): a part that short of a random key does not occur in captions by chance, and a part
shorter than that says too little of the key to matter. A ``Bearer`` token is redacted whatever it is.
"""

from __future__ import annotations

import base64
import html
import logging
import re
from typing import Iterable

MARK = "[redacted]"
RUN = 8  # the shortest part of the key that is redacted (the whole key when it is shorter)
# one encoded character, escaped once or more (JSON holding JSON: \\\\u0073; a URL in a URL: %252D)
_ENCODED = re.compile(r"%(?:25)*[0-9A-Fa-f]{2}|\\+u[0-9A-Fa-f]{4}|\\+[/\"]|&(?:amp;)*#[xX][0-9A-Fa-f]{1,6};"
                      r"|&(?:amp;)*#[0-9]{1,7};")
_BEARER = re.compile(r"(?i)(bearer\s+)[A-Za-z0-9._~+/=\-]+")


def _decoded(text: str) -> tuple[str, list[int]]:
    """``text`` with every encoded character decoded and case-folded, and for each character of the
    result the offset in ``text`` where its encoding starts (plus one entry for the end)."""
    out: list[str] = []
    starts: list[int] = []
    pos = 0
    for m in _ENCODED.finditer(text):
        for i in range(pos, m.start()):
            out.append(text[i].lower())
            starts.append(i)
        token = m.group(0)
        if token.startswith("%"):
            ch = chr(int(token[-2:], 16))
        elif token.startswith("\\"):
            body = token.lstrip("\\")
            ch = chr(int(body[1:], 16)) if body.startswith("u") else body
        else:
            ch = html.unescape(token.replace("&amp;", "&"))[:1] or token
        out.append(ch.lower())
        starts.append(m.start())
        pos = m.end()
    for i in range(pos, len(text)):
        out.append(text[i].lower())
        starts.append(i)
    starts.append(len(text))
    return "".join(out), starts


def _grams(forms: Iterable[str], k: int) -> set[str]:
    return {f[i:i + k] for f in forms if len(f) >= k for i in range(len(f) - k + 1)}


def _base64_forms(key: bytes) -> list[str]:
    """Base64 of ``key`` at each byte alignment, less the edge characters that depend on its neighbours,
    in the standard and the URL-safe alphabet."""
    forms = []
    for pad in range(3):
        enc = base64.b64encode(b"\0" * pad + key).decode("ascii").rstrip("=")
        lead = (pad * 4 + 2) // 3  # characters that carry the padding bytes
        tail = (len(enc) - 1) if (pad + len(key)) % 3 else len(enc)
        core = enc[lead:tail]
        forms += [core, core.replace("+", "-").replace("/", "_")]
    return forms


class Redactor:
    """``redactor(text)``: ``text`` with every form of the key (see the module docstring) as ``[redacted]``."""

    def __init__(self, key: str, *, run: int = RUN) -> None:
        self.key = key
        self.k = max(1, min(run, len(key)))
        self._plain = _grams([key.lower()], self.k) if key else set()
        raw = key.encode("utf-8")
        self._b64k = max(self.k + 4, 12)
        self._b64 = _grams(_base64_forms(raw), self._b64k) if key else set()
        self._hex = _grams([raw.hex()], 2 * self.k) if key else set()

    def spans(self, text: str) -> list[tuple[int, int]]:
        """Merged ``(start, end)`` offsets of ``text`` that hold a form of the key."""
        found: list[tuple[int, int]] = []
        if self._plain:
            folded, starts = _decoded(text)
            k = self.k
            for i in range(len(folded) - k + 1):
                if folded[i:i + k] in self._plain:
                    found.append((starts[i], starts[i + k]))
        for grams, k, view in ((self._b64, self._b64k, text), (self._hex, 2 * self.k, text.lower())):
            for i in range(len(view) - k + 1):
                if view[i:i + k] in grams:
                    found.append((i, i + k))
        found.sort()
        merged: list[tuple[int, int]] = []
        for a, b in found:
            if merged and a <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(merged[-1][1], b))
            else:
                merged.append((a, b))
        return merged

    def __call__(self, text: str) -> str:
        if not text:
            return text
        out, pos = [], 0
        for a, b in self.spans(text):
            out += [text[pos:a], MARK]
            pos = b
        out.append(text[pos:])
        return _BEARER.sub(r"\1" + MARK, "".join(out))


class RedactingFilter(logging.Filter):
    """A logging filter that rewrites a record's message through a :class:`Redactor` (installed on the
    loggers of the HTTP stack while an HTTP captioner is open: httpx logs every request URL)."""

    def __init__(self, redactor: Redactor) -> None:
        super().__init__()
        self.redactor = redactor

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        clean = self.redactor(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True
