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


@pytest.fixture(scope="session")
def composed_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small real composed dataset shared by the export tests (tests marked ``blender`` use it): demo
    library -> real ingest -> real compose of 2 scenes of the train split at 96 px (configs/quick.toml,
    16-24 objects drawn per scene so that classes keep a few visible instances; seeds 5 and 6 give two
    classes in each image and a visible distractor)."""
    from test_usd_stage import build_demo_catalog

    from mixcount.cli import main

    root = tmp_path_factory.mktemp("composed_dataset")
    build_demo_catalog(root, n_objects=12).close()
    out = root / "out"
    rc = main(["--db", str(root / "catalog.db"), "--config", "quick", "--set", "scene.n_objects=[16,24]",
               "compose", "--n", "2", "--split", "train", "--seed", "5", "--resolution", "96", "--out", str(out)])
    assert rc == 0
    return out
