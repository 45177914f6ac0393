"""One exception tree for mixcount.

MixcountError
  ConfigError        unknown key, wrong type, unreadable config file
  CatalogError       database unreachable/unwritable, missing object, bad ingest path
    IngestError      one object could not be ingested (recorded as `broken`, batch goes on)
  CaptionError       captioner failure for one object (recorded, batch goes on)
  CompositionError   scene sampling / USD writing failed
  RenderError        Blender worker failed, timed out or produced invalid output

Only ``mixcount.cli`` turns these into messages and exit codes.
"""

from __future__ import annotations


class MixcountError(Exception):
    """Base of every error mixcount raises on purpose."""


class ConfigError(MixcountError):
    """Configuration is invalid (unknown key, wrong type, unreadable file)."""


class CatalogError(MixcountError):
    """The catalog database or a catalog look-up failed."""


class IngestError(CatalogError):
    """One object could not be ingested; ``reason`` is stored as the object's error."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class CaptionError(MixcountError):
    """A captioner could not produce a valid caption set for one object."""


class CompositionError(MixcountError):
    """A scene could not be sampled or written."""


class RenderError(MixcountError):
    """A Blender worker failed, timed out or produced invalid output."""
