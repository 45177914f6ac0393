"""Catalog ids follow the library, not the race between ingest's workers: with two workers, a heavy model
listed first still gets the first id, and the same library ingested into two catalogs gives the same ids.
The compositor draws objects by id, so this is what makes one library and one seed the same dataset."""

from __future__ import annotations

from pathlib import Path

import trimesh
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject
from mixcount.config import load_config


def _library(root: Path) -> Path:
    """Six plain PLY models; the first by name is ~80 times heavier than the others, so it finishes last."""
    root.mkdir()
    trimesh.creation.icosphere(subdivisions=6, radius=0.05).export(root / "a_heavy_sphere.ply")
    for i in range(5):
        trimesh.creation.box(extents=(0.02 + 0.01 * i, 0.03, 0.04)).export(root / f"b_box_{i}.ply")
    return root


def _ids(db: Path, library: Path) -> dict[str, int]:
    catalog = open_catalog(f"sqlite:///{db}", data_dir=str(db.parent / "data"))
    try:
        summary = ingest_paths(catalog, [library], config=load_config([], ["ingest.workers=2"]))
        assert summary.new == 6 and summary.broken == 0
        with catalog.session() as s:
            return {o.model_path.split("/")[-1]: int(o.id) for o in s.scalars(select(CatalogObject)).all()}
    finally:
        catalog.close()


def test_ids_follow_the_library_whichever_worker_finishes_first(tmp_path: Path) -> None:
    library = _library(tmp_path / "lib")
    first, second = _ids(tmp_path / "one.db", library), _ids(tmp_path / "two.db", library)
    assert first == second
    assert [name for name, _ in sorted(first.items(), key=lambda kv: kv[1])] == sorted(first)


def test_a_worker_that_dies_is_retried_alone_and_the_order_holds(tmp_path: Path, monkeypatch) -> None:
    """A model whose analysis kills its worker process (a segfault in a mesh library) takes the pool with it:
    that model is recorded as crashed, every other model is still analysed, and results come in job order."""
    import os

    import mixcount.catalog.mesh as mesh
    from mixcount.catalog.analysis_pool import analyse_all

    real = mesh.analyse_model

    def dies_on_crash(**kwargs):  # type: ignore[no-untyped-def]
        if kwargs["model_path"].endswith("crash.ply"):
            os._exit(139)  # what a segfault looks like from the pool
        return real(**kwargs)

    monkeypatch.setattr(mesh, "analyse_model", dies_on_crash)  # the pool's workers are forked: they see it
    names = ["a.ply", "b.ply", "crash.ply", "d.ply", "e.ply"]
    for name in names:
        trimesh.creation.box(extents=(0.02, 0.03, 0.04)).export(tmp_path / name)
    kwargs = {"collision_dir": str(tmp_path / "collision"), "face_budget": 500, "units": "m", "units_reason": "",
              "up_axis": "Z", "proxy_max_vertices": 64, "collision_source": None, "facts_face_budget": 200_000}
    seen: list[tuple[str, bool, str | None]] = []
    analyse_all([(n, {**kwargs, "model_path": str(tmp_path / n)}) for n in names], 2,
                lambda job, facts, error: seen.append((job, facts is not None, error)))
    assert [s[0] for s in seen] == names
    assert [s[1] for s in seen] == [True, True, False, True, True]
    assert seen[2][2] == "mesh analysis crashed its worker process"
