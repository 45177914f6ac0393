"""Shared pytest fixtures. Engine tiers are marked (blender, network, browser, ray); in CI (CI=true)
a missing engine is a failure, never a skip.

What several modules need is built once per session here, not once per module (the suite must stay
under 10 minutes on a 2-core machine): the seed-0 demo library (``demo_library``), that library ingested
and rendered (``rendered_demo_catalog``), the small demo catalogs of ``build_demo_catalog``
(``demo_catalog_copy``) and one composed dataset (``composed_dataset``). A session fixture's files are
read only: a test that changes a catalog or a library works on a copy (copying a catalog folder takes
milliseconds, building it seconds to a minute).

``make test`` runs the suite in two pytest-xdist processes (``--dist loadfile``: a module's tests and its
module fixtures stay in one process). A session fixture is then built once for both: the first process
to need it builds it under the run's shared temporary folder while holding a file lock, the other waits
for the lock and reads what was built (``_built_once``)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Callable

import pytest
from filelock import FileLock

IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
PROJECT_ROOT = Path(__file__).resolve().parent.parent


def _built_once(factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name`` that ``build(folder)`` filled, built once per test run. In one process: a fresh
    temporary folder. Under pytest-xdist (``PYTEST_XDIST_WORKER`` set), in the run's temporary root shared
    by every worker, behind a file lock; a ``.built`` marker written after ``build`` returns tells a later
    worker the folder is complete (a build that raised leaves no marker, so the next worker builds anew)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        folder = factory.mktemp(name)
        build(folder)
        return folder
    shared = factory.getbasetemp().parent  # pytest-of-<user>/pytest-<n>/: the run's root, above each popen-gw<k>
    folder, marker = shared / f"shared-{name}", shared / f"shared-{name}.built"
    with FileLock(str(shared / f"shared-{name}.lock")):
        if not marker.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            build(folder)
            marker.touch()
    return folder


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
            built[n_objects] = _built_once(tmp_path_factory, f"demo_catalog_{n_objects}",
                                           lambda folder: build_demo_catalog(folder, n_objects=n_objects).close())
        shutil.copytree(built[n_objects], dest, symlinks=True, dirs_exist_ok=True)
        return dest

    return copy


@pytest.fixture(scope="session")
def demo_library(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """(folder, ground truth) of the whole seed-0 demo library, generated once per session. Read only:
    a test that changes files of a library generates its own."""
    from mixcount.demo.library import generate_demo_library

    def build(folder: Path) -> None:
        generate_demo_library(folder / "demo", seed=0)

    folder = _built_once(tmp_path_factory, "demo_library", build)
    root = folder / "demo"  # the truth as the library wrote it (JSON: pairs are lists), the same in every process
    return root, json.loads((root / "ground_truth.json").read_text())


RENDERED_DEMO = ["--config", "configs/quick.toml", "--set", "canonical_render.resolution=64", "--set", "canonical_render.samples=2"]


@pytest.fixture(scope="session")
def rendered_demo_catalog(tmp_path_factory: pytest.TempPathFactory, demo_library: tuple[Path, dict]) -> tuple[Path, dict]:
    """(catalog folder, ground truth): the whole seed-0 demo library (``demo_library``) ingested and rendered
    through the CLI at 64 px / 2 spp (``RENDERED_DEMO``: what ``make demo``'s curation sees, small), before
    any filter. Built once (bpy: the slow part); tests copy the folder (``catalog.db`` and its renders)
    before they filter it."""
    from mixcount.cli import main

    library, truth = demo_library

    def build(root: Path) -> None:
        base = ["--db", str(root / "db" / "catalog.db"), *RENDERED_DEMO]
        (root / "db").mkdir()
        assert main(base + ["catalog", "ingest", str(library)]) == 0
        assert main(base + ["catalog", "render"]) == 0

    return _built_once(tmp_path_factory, "rendered_demo", build) / "db", truth


@pytest.fixture(scope="session")
def composed_dataset(tmp_path_factory: pytest.TempPathFactory, demo_catalog_copy: Callable[[Path, int], Path]) -> Path:
    """One small real composed dataset shared by the export tests (tests marked ``blender`` use it): demo
    library -> real ingest -> real compose of 2 scenes of the train split at 96 px (configs/quick.toml,
    16-24 objects drawn per scene so that classes keep a few visible instances; seeds 5 and 6 give two
    classes in each image and a visible distractor)."""
    from mixcount.cli import main

    def build(root: Path) -> None:
        demo_catalog_copy(root, 12)
        rc = main(["--db", str(root / "catalog.db"), "--config", "quick", "--set", "scene.n_objects=[16,24]",
                   "compose", "--n", "2", "--split", "train", "--seed", "5", "--resolution", "96", "--out", str(root / "out")])
        assert rc == 0

    return _built_once(tmp_path_factory, "composed_dataset", build) / "out"
