"""Reading a decisions file (``mixcount-review-v1``) as `catalog review import` must: bounded (a file over
:data:`MAX_FILE_MB`, JSON nested deeper than Python can parse, an id no database integer holds are one
line each, never a traceback), its times checked (a time in the future would outrank every later
decision, so it is refused), its ``catalog`` field compared with the catalog it is imported into, and
each refused entry named with the line of the file that holds it."""

from __future__ import annotations

import json
import json.scanner
import os
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError

from mixcount.errors import CatalogError

FORMAT = "mixcount-review-v1"
MAX_FILE_MB = 512  # about 3 million entries as the review page writes them
FUTURE_SLACK = timedelta(minutes=10)  # a clock that runs a little ahead is not a decision from the future
MAX_ID = 2**63 - 1  # the largest id SQLite (and every other database's BIGINT) holds


def short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (a name or number from the file may be any length)."""
    try:
        text = repr(value)
    except ValueError:  # an int beyond Python's digit limit for str()
        text = f"<an integer of about {value.bit_length() * 30103 // 100000} digits>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def is_id(value: Any) -> bool:
    """An object id the catalog can hold: a JSON integer (not true/false) from 1 to :data:`MAX_ID`."""
    return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= MAX_ID


def load_decisions(path: Path) -> tuple[dict[str, Any], str]:
    """The file's JSON object and its text, shape-checked (raises CatalogError with one line)."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise CatalogError(f"decisions file not found: {path}") from None
    except OSError as exc:
        raise CatalogError(f"cannot read decisions file {path}: {exc.strerror or exc}") from None
    if size > MAX_FILE_MB * 2**20:
        raise CatalogError(f"decisions file {path} is {size / 2**20:.0f} MB, more than the {MAX_FILE_MB} MB a "
                           "decisions file may have; split it (each part is imported on its own)")
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text)
    except (OSError, ValueError) as exc:
        raise CatalogError(f"cannot read decisions file {path}: {exc}") from None
    except RecursionError:
        raise CatalogError(f"decisions file {path} is nested too deeply to be a decisions file") from None
    except MemoryError:
        raise CatalogError(f"decisions file {path} is too large to read into memory") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("decisions"), list):
        raise CatalogError(f"{path} is not a {FORMAT} decisions file")
    if not isinstance(data.get("pairs", []), list):
        raise CatalogError(f"{path}: 'pairs' is not a list")
    return data, text


def parse_time(value: Any, *, now: datetime | None = None) -> datetime | None:
    """A decision time (ISO-8601; ``Z`` or an offset) as naive UTC to the millisecond; None when absent.
    Raises CatalogError when it is not a time or, given ``now``, lies in the future."""
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise CatalogError(f"time {short(value)} is not an ISO-8601 string")
    try:
        dt = datetime.fromisoformat(value.replace("Z", "+00:00"))
        if dt.tzinfo is not None:
            dt = dt.astimezone(timezone.utc).replace(tzinfo=None)
    except (ValueError, OverflowError):
        raise CatalogError(f"time {short(value)} is not an ISO-8601 time") from None
    dt = dt.replace(microsecond=(dt.microsecond // 1000) * 1000)
    if now is not None and dt > now + FUTURE_SLACK:
        raise CatalogError(f"time {short(value)} is in the future (now {now.isoformat(timespec='seconds')}Z): "
                           "it would outrank every later decision")
    return dt


def entry_lines(text: str) -> dict[tuple[str, int], tuple[int, int]]:
    """("decisions" | "pairs", index) -> (start, end) offsets of that entry in ``text``. Parses the file
    again with the pure-Python scanner (slow: called only to name the lines of refused entries)."""
    spans: dict[int, tuple[int, int]] = {}
    decoder = json.JSONDecoder()
    plain = decoder.parse_object  # type: ignore[attr-defined]

    def parse_object(s_and_end: tuple[str, int], *args: Any) -> tuple[Any, int]:
        obj, end = plain(s_and_end, *args)
        spans[id(obj)] = (s_and_end[1] - 1, end)
        return obj, end

    decoder.parse_object = parse_object  # type: ignore[attr-defined]
    decoder.scan_once = json.scanner.py_make_scanner(decoder)  # type: ignore[attr-defined]
    try:
        data = decoder.decode(text)
    except (ValueError, RecursionError):
        return {}
    out = {}
    for key in ("decisions", "pairs"):
        entries = data.get(key) if isinstance(data, dict) else None
        for k, entry in enumerate(entries if isinstance(entries, list) else []):
            if id(entry) in spans:
                out[(key, k)] = spans[id(entry)]
    return out


def where(text: str, spans: dict[tuple[str, int], tuple[int, int]], key: str, k: int, field: str | None) -> str:
    """" (line N)" of entry ``k`` of ``key`` (of its ``field`` when the entry names it), else ""."""
    span = spans.get((key, k))
    if span is None:
        return ""
    at = span[0]
    if field is not None:
        found = text.find(f'"{field}"', span[0], span[1])
        at = found if found >= 0 else at
    return f" (line {text.count(chr(10), 0, at) + 1})"


def _database(url: str) -> tuple[str, str | None]:
    """(backend, database file or name) of a catalog URL; raises ArgumentError when it is none."""
    parsed = make_url(url)
    return parsed.get_backend_name(), parsed.database


def same_catalog(named: str, here: str) -> bool:
    """Whether a file's ``catalog`` field names the catalog at URL ``here``: the same URL, or the same
    SQLite file (through links, or a relative path that ends the path of this one)."""
    if named == here:
        return True
    try:
        (b1, d1), (b2, d2) = _database(named), _database(here)
    except ArgumentError:
        return False
    if b1 != b2 or not d1 or not d2:
        return False
    if b1 != "sqlite":
        return make_url(named).render_as_string(hide_password=True) == make_url(here).render_as_string(hide_password=True)
    a, b = Path(d1), Path(d2)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    if not a.is_absolute():
        return b.parts[-len(a.parts):] == a.parts
    return os.path.realpath(a) == os.path.realpath(b)


def check_catalog(data: dict[str, Any], path: Path, here: str, *, other_catalog: bool) -> None:
    """Refuse a file exported from another catalog unless ``other_catalog`` (the user says it is meant)."""
    named = data.get("catalog")
    if named is None or named == "" or other_catalog:
        return
    if not isinstance(named, str):
        raise CatalogError(f"decisions file {path}: 'catalog' {short(named)} is not a catalog URL")
    if not same_catalog(named, here):
        raise CatalogError(
            f"decisions file {path} was exported from catalog {short(named, 200)}, not this one "
            f"({short(here, 200)}); nothing applied. Give --other-catalog if it is meant for this catalog "
            "(ids and names are still checked)")
