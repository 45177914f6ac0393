"""Real parts under a millimetre cube are objects, not degenerate meshes: FreeCAD's IDF library (Debian's
``freecad-common``: SMD resistors, diodes, transistors as STEP in millimetres) ingested as it ships.
The filter's zero-volume test was an absolute 1e-9 m^3 and excluded the 1.8 mm SOD-523 diode (0.8 mm^3);
it is now relative to the object's size, as the zero-area test always was."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from public_packages import deb_tree
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.config import load_config
from mixcount.curation.finding.catalog_filter import run_filter

PARTS = ("SOD_523", "0805_SMD", "1206_SMD", "SOT23")  # with their datasheet length in mm
LENGTH_MM = {"SOD_523": 1.8, "0805_SMD": 2.0, "1206_SMD": 3.2, "SOT23": 2.9}


def test_millimetre_parts_keep_their_size_and_are_not_degenerate(tmp_path: Path) -> None:
    root, why = deb_tree("freecad-common")
    if root is None:
        pytest.skip(why)
    source = root / "usr" / "share" / "freecad" / "Mod" / "Idf" / "Idflibs"
    library = tmp_path / "Idflibs"
    library.mkdir()
    for name in PARTS:
        shutil.copy(source / f"{name}.stp", library)
    catalog = open_catalog(f"sqlite:///{tmp_path / 'c.db'}", data_dir=str(tmp_path / "data"))
    try:
        config = load_config(["quick"])
        assert ingest_paths(catalog, [library], config=config).new == len(PARTS)
        run_filter(catalog, config, ground_truth=False)
        with catalog.session() as s:
            objects = {o.name: o for o in s.scalars(select(CatalogObject))}
            degenerate = {o.name for o in objects.values()
                          if s.scalar(select(Flag).where(Flag.object_id == o.id, Flag.kind == "degenerate"))}
            assert {n: round(max(o.dim_x, o.dim_y, o.dim_z) * 1000, 1) for n, o in objects.items()} == LENGTH_MM
            assert degenerate == set() and {o.status for o in objects.values()} == {"active"}
    finally:
        catalog.close()
