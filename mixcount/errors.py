"""One exception tree for mixcount.

MixcountError
  ConfigError        unknown key, wrong type, unreadable config file
  CatalogError       database unreachable/unwritable, missing object, bad ingest path
    IngestError      one object could not be ingested (recorded as `broken`, batch goes on)
  CaptionError       captioner failure for one object (recorded, batch goes on)
  CompositionError   scene sampling / USD writing failed
  RenderError        Blender worker failed, timed out or produced invalid output
  StorageError       an output folder cannot take the run's files: no space, read-only, no permission
  AssetError         a file a scene needs (model, texture, environment map) is missing or unreadable
  DatasetError       a dataset's files do not match their record, or a scene cannot be merged

StorageError and AssetError stop a compose run: no other seed could succeed (docs/faults.md).

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


class StorageError(MixcountError):
    """An output folder cannot take the run's files (no space left, read-only, no permission): a fault
    that no other seed can fix, so a compose run stops on it."""


class AssetError(MixcountError):
    """A file a scene needs (an object's model, a floor texture, an environment map) is missing or
    unreadable: a compose run stops on it instead of drawing seed after seed."""


class DatasetError(MixcountError):
    """A dataset's files do not match their record (``mixcount verify``), or a scene cannot be merged."""


def os_error_line(exc: OSError) -> str:
    """One line for an OSError: its cause and the path it names (``No space left on device: /out/x``)."""
    cause = exc.strerror or str(exc) or type(exc).__name__
    path = exc.filename if exc.filename is not None else None
    return f"{cause}: {path}" if path is not None else cause
