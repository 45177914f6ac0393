"""A filter re-run with other settings computes its figures anew (issue 69, found while measuring): the
pair figures that ``catalog filter`` keeps between runs (:class:`~mixcount.curation.finding.filter_items.LayoutCache`,
beside the descriptors) were keyed by the two objects and the code's version only. The aligned distance
depends on ``[filter] copy_max_squash`` and ``match_quantile``, the primitive distance on
``match_quantile``, the colour layout on ``look_layout`` (above it, rotations are searched); a re-run
after changing one read the figures of the old value and reported flags that the new settings do not give.

A 3-object demo library (with its planted copies) (real SQLite catalog through the CLI, no renders) is filtered with the defaults, then
again with another squash bound and quantile: the second run's flags are those of a cold run with those
settings (a copy of the catalog without the cache), and its alignment and primitive figures sit beside
the first's under their own settings (the colour layouts, which these settings do not change, are shared)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.cli import main
from mixcount.config import load_config
from mixcount.demo.library import generate_demo_library

OTHER = ["--set", "filter.copy_max_squash=1.05", "--set", "filter.match_quantile=0.75"]


def _flags(db: Path) -> list[tuple]:
    catalog = open_catalog(str(db), data_dir="")
    try:
        with catalog.session() as s:
            name = {o.id: o.name for o in s.scalars(select(CatalogObject))}
            return sorted((name[f.object_id], name.get(f.pair_object_id) or "", f.kind, f.reason)
                          for f in s.scalars(select(Flag)))
    finally:
        catalog.close()


def _figures(folder: Path) -> dict[str, float]:
    (cache,) = (folder / "descriptors").glob("layouts_*.json")
    return json.loads(cache.read_text())


def test_a_rerun_with_other_settings_computes_its_figures_anew(tmp_path, capsys):
    generate_demo_library(tmp_path / "lib", seed=3, n_objects=3)
    warm, cold = tmp_path / "warm", tmp_path / "cold"
    warm.mkdir()
    base = ["--config", "configs/quick.toml"]
    assert main(["--db", str(warm / "catalog.db"), *base, "catalog", "ingest", str(tmp_path / "lib")]) == 0
    shutil.copytree(warm, cold)
    assert main(["--db", str(warm / "catalog.db"), *base, "catalog", "filter"]) == 0
    defaults = _figures(warm)
    assert main(["--db", str(warm / "catalog.db"), *base, *OTHER, "catalog", "filter"]) == 0
    assert main(["--db", str(cold / "catalog.db"), *base, *OTHER, "catalog", "filter"]) == 0
    capsys.readouterr()
    assert _flags(warm / "catalog.db") == _flags(cold / "catalog.db")
    both, other = _figures(warm), _figures(cold)
    assert set(defaults) | set(other) == set(both)
    shaped = ("shape-", "stretch-", "primitive-")  # the figures these settings change; the colour layouts stay shared
    assert not {k for k in defaults if k.startswith(shaped)} & {k for k in other if k.startswith(shaped)}
    shapes = {k for k in other if k.startswith("shape-")}
    assert shapes and all("/copy_max_squash=1.05/match_quantile=0.75:" in k for k in shapes), sorted(shapes)[:3]
    th = load_config(["configs/quick.toml"]).filter
    default = f"/copy_max_squash={th.copy_max_squash:.9g}/match_quantile={th.match_quantile:.9g}:"
    moved = [k for k in shapes if both[k] != both[k.replace("/copy_max_squash=1.05/match_quantile=0.75:", default)]]
    assert moved, "the settings changed no aligned distance: the test would not see a stale figure"
    print(f"\n{len(shapes)} alignments, {len(moved)} of them another figure under the other settings")
