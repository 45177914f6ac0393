"""Shared pytest fixtures. Engine tiers are marked (blender, network, browser, ray); in CI (CI=true)
a missing engine is a failure, never a skip.

What several modules need is built once per session here, not once per module (the suite must stay
under 10 minutes on a 2-core machine): the seed-0 demo library (``demo_library``), that library ingested
and rendered (``rendered_demo_catalog``), the small demo catalogs of ``build_demo_catalog``
(``demo_catalog_copy``) and one composed dataset (``composed_dataset``). A session fixture's files are
read only: a test that changes a catalog or a library works on a copy (copying a catalog folder takes
milliseconds, building it seconds to a minute)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

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
def demo_catalog_copy(tmp_path_factory: pytest.TempPathFactory) -> Callable[[Path, int], Path]:
    """``copy(dest, n_objects)``: a copy at ``dest`` of a demo catalog folder (``build_demo_catalog``:
    the seed-0 demo library of ``n_objects`` in ``lib/``, ingested with configs/quick.toml, every active
    object in train). Each size is built once per session into a folder no test touches; every caller gets
    its own copy (catalog.db, library and ingest's files: a few MB, copied in milliseconds) that it may
    change. Model paths are stored absolute: a copy reads the template's lib/ and proxies, which no test writes."""
    from test_usd_stage import build_demo_catalog

    built: dict[int, Path] = {}

    def copy(dest: Path, n_objects: int) -> Path:
        if n_objects not in built:
            template = tmp_path_factory.mktemp(f"demo_catalog_{n_objects}")
            build_demo_catalog(template, n_objects=n_objects).close()
            built[n_objects] = template
        shutil.copytree(built[n_objects], dest, symlinks=True, dirs_exist_ok=True)
        return dest

    return copy


@pytest.fixture(scope="session")
def demo_library(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """(folder, ground truth) of the whole seed-0 demo library, generated once per session. Read only:
    a test that changes files of a library generates its own."""
    from mixcount.demo.library import generate_demo_library

    root = tmp_path_factory.mktemp("demo_library") / "demo"
    return root, generate_demo_library(root, seed=0)


RENDERED_DEMO = ["--config", "configs/quick.toml", "--set", "canonical_render.resolution=64", "--set", "canonical_render.samples=2"]


@pytest.fixture(scope="session")
def rendered_demo_catalog(tmp_path_factory: pytest.TempPathFactory, demo_library: tuple[Path, dict]) -> tuple[Path, dict]:
    """(catalog folder, ground truth): the whole seed-0 demo library (``demo_library``) ingested and rendered
    through the CLI at 64 px / 2 spp (``RENDERED_DEMO``: what ``make demo``'s curation sees, small), before
    any filter. Built once (bpy: the slow part); tests copy the folder (``catalog.db`` and its renders)
    before they filter it, and bench/curation.py --smoke reads it as its ``db_rendered``."""
    from mixcount.cli import main

    library, truth = demo_library
    root = tmp_path_factory.mktemp("rendered_demo")
    base = ["--db", str(root / "db" / "catalog.db"), *RENDERED_DEMO]
    (root / "db").mkdir()
    assert main(base + ["catalog", "ingest", str(library)]) == 0
    assert main(base + ["catalog", "render"]) == 0
    return root / "db", truth


@pytest.fixture(scope="session")
def composed_dataset(tmp_path_factory: pytest.TempPathFactory, demo_catalog_copy: Callable[[Path, int], Path]) -> Path:
    """One small real composed dataset shared by the export tests (tests marked ``blender`` use it): demo
    library -> real ingest -> real compose of 2 scenes of the train split at 96 px (configs/quick.toml,
    16-24 objects drawn per scene so that classes keep a few visible instances; seeds 5 and 6 give two
    classes in each image and a visible distractor)."""
    from mixcount.cli import main

    root = demo_catalog_copy(tmp_path_factory.mktemp("composed_dataset"), 12)
    out = root / "out"
    rc = main(["--db", str(root / "catalog.db"), "--config", "quick", "--set", "scene.n_objects=[16,24]",
               "compose", "--n", "2", "--split", "train", "--seed", "5", "--resolution", "96", "--out", str(out)])
    assert rc == 0
    return out
