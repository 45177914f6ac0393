"""The installed mixcount's version (one source of truth: pyproject.toml), in the foundation room: a module
that records it (export manifests, ``--version``) imports this, not the package root (whose lazy API
reaches the top room)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mixcount")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
