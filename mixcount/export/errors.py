"""The export area's error, defined in the one exception tree (:mod:`mixcount.errors`)."""

from __future__ import annotations

from mixcount.errors import ExportError

__all__ = ["ExportError"]
