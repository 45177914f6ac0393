"""The installed mixcount's version (one source of truth: pyproject.toml), in the foundation room: a module
that records it (export manifests, ``--version``) imports this, not the package root (whose lazy API
reaches the top room).

Read on first use (PEP 562), not at import: every mixcount process imports the package, and the lookup
(``importlib.metadata``, which scans the installed distributions) cost each one ~35 ms, about 10 CPU-seconds
of the test suite's ~300 processes; only ``--version`` and the export manifests ask for it."""

from __future__ import annotations

from functools import lru_cache


@lru_cache(maxsize=1)
def installed_version() -> str:
    """The installed distribution's version; ``0+unknown`` in a source tree that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mixcount")
    except PackageNotFoundError:
        return "0+unknown"


def __getattr__(name: str) -> str:
    if name == "__version__":
        return installed_version()
    raise AttributeError(f"module 'mixcount.version' has no attribute {name!r}")
