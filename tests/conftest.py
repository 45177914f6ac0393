"""Shared pytest fixtures. Engine tiers are marked (blender, network, browser, ray); in CI (CI=true)
a missing engine is a failure, never a skip."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
PROJECT_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def db_url(tmp_path: Path) -> str:
    """A fresh SQLite catalog file in tmp_path (migrated on first open)."""
    return f"sqlite:///{tmp_path / 'catalog.db'}"


@pytest.fixture
def catalog(db_url: str):
    from mixcount.catalog.db import open_catalog

    cat = open_catalog(db_url, data_dir="")
    yield cat
    cat.close()
