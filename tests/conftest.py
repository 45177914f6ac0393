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


def convert_pool_assets(catalog) -> None:
    """Every active object's USD asset in ``catalog.usd_assets_dir``, converted as compose converts the assets
    of a scene (:func:`mixcount.usd.stage.convert_object_asset`, with the configs/quick.toml palette's look for
    an untextured object; a container with its collision parts). A compose finds them current (same source,
    frame, look and proxy) and converts nothing again; one with another look converts its own."""
    from mixcount.catalog.pool_loader import load_pool
    from mixcount.config import load_config
    from mixcount.usd.stage import convert_object_asset

    with catalog.session() as session:
        pool = load_pool(session, palette=load_config(["quick"]).palette)
    for o in pool:
        convert_object_asset(o, Path(catalog.usd_assets_dir), container=o.container)


@pytest.fixture(scope="session")
def demo_catalog_copy(tmp_path_factory: pytest.TempPathFactory) -> Callable[[Path, int], Path]:
    """``copy(dest, n_objects)``: a copy at ``dest`` of a demo catalog folder (``build_demo_catalog``:
    the seed-0 demo library of ``n_objects`` in ``lib/``, ingested with configs/quick.toml, every active
    object in train, and every object's USD asset converted as compose converts it: ``convert_pool_assets``).
    Each size is built once per session into a folder no test touches; every caller gets its own copy
    (catalog.db, library, ingest's files and ``usd_assets/``: a few MB, copied in milliseconds) that it may
    change. Model paths are stored absolute: a copy reads the template's lib/ and proxies, which no test writes.
    A compose from a copy finds its assets converted, as a user's second compose from one catalog does (the
    conversion itself, a container's convex parts included, is tested on catalogs of their own:
    tests/test_usd_assets.py, tests/test_collision_proxies.py, tests/test_missing_files.py)."""
    from test_usd_stage import build_demo_catalog

    built: dict[int, Path] = {}

    def build(folder: Path, n_objects: int) -> None:
        catalog = build_demo_catalog(folder, n_objects=n_objects)
        try:
            convert_pool_assets(catalog)
        finally:
            catalog.close()

    def copy(dest: Path, n_objects: int) -> Path:
        if n_objects not in built:
            built[n_objects] = _built_once(tmp_path_factory, f"demo_catalog_{n_objects}",
                                           lambda folder: build(folder, n_objects))
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


# The modules that take longest (seconds of one `make test` on the 2-core machine, 2026-12-06), run first.
# `make test` hands whole modules to two processes in the order collected (``--no-loadscope-reorder``; xdist's
# own order is by number of tests, which put the 93 s test_curate_demo.py, one test, near the end and left
# the other process idle for its last minute). Longest first leaves only short modules for the end, so both
# processes finish within a few seconds of each other. A module not named here runs after these, in file
# order; re-measure with ``pytest --junitxml`` and reorder when a module's time changes a lot.
SLOWEST_MODULES_FIRST = (
    "test_benches.py",  # 176 s
    "test_captions_named.py",  # 112 s
    "test_curate_demo.py",  # 93 s
    "test_split_library.py",  # 68 s
    "test_ray_executor.py",  # 68 s
    "test_ray_catalog.py",  # ~120 s alone on a loaded machine (issue 69: catalog steps on Ray)
    "test_hostile_library.py",  # 60-75 s alone on a loaded machine (issue 68)
    "test_readme_flow.py",  # 57 s
    "test_cross_source.py",  # 45 s
    "test_blender_worker.py",  # 43 s
    "test_cross_source_shape.py",  # 43 s
    "test_curate_capture.py",  # 41 s
    "test_portable_dataset.py",  # 34 s
    "test_count_compose.py",  # 34 s
    "test_render_quality.py",  # 28 s
    "test_rerender.py",  # 25 s
    "test_settle_ahead.py",  # 24 s
    "test_collision_proxies.py",  # 23 s
    "test_cli_catalog.py",  # 21 s
    "test_two_catalogs.py",  # 20 s
    "test_mesh_bounds.py",  # 19 s
    "test_capture_copies.py",  # 19 s
    "test_faults_catalog.py",  # 18 s
    "test_compose_device.py",  # 15 s
    "test_ingest.py",  # 15 s
    "test_variants.py",  # 15 s
    "test_renders.py",  # 15 s
    "test_compose_settings.py",  # 15 s
    "test_wheel.py",  # 14 s
    "test_curate_untextured.py",  # 13 s
    "test_bundled_environments.py",  # 12 s
    "test_sheets.py",  # 12 s
    "test_review_browser.py",  # 12 s
    "test_compose_views.py",  # 11 s
    "test_walk_once.py",  # 10 s
    "test_demo_library.py",  # 10 s
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Modules in :data:`SLOWEST_MODULES_FIRST`'s order, then the rest; a module's own tests keep their order."""
    rank = {name: k for k, name in enumerate(SLOWEST_MODULES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable
