"""Errors of the export area; MixcountErrors, so the CLI prints them as messages (exit code 2)."""

from __future__ import annotations

from mixcount.errors import MixcountError


class ExportError(MixcountError):
    """A dataset could not be exported: not a composed dataset, unknown split or format, bad output folder."""
