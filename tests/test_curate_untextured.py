"""An untextured library as a new user makes one (issue 57; tests/untextured_library.py: 20 models of
Debian's prusa-slicer and assimp-testmodels and PyPI's metaworld), through the CLI with real bpy renders
(64 px): a grey surface carries no evidence that two objects are one.

Before issue 57: 3 objects excluded (a hex nut as a copy of a hockey puck although "real sizes differ
63.51x", a cup of a mug, a pyramid of a cone) and 3 pairs to decide. Now: none excluded, no duplicate
flag, at most 3 pairs to decide, and the nut / puck pair a look-alike at most, its size quoted."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sqlalchemy import select
from untextured_library import MODELS, write_library

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.cli import main
from mixcount.curation.flag_kinds import DUPLICATE_KINDS, severity

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_untextured_library_excludes_nothing(tmp_path, capsys):
    lib, why = write_library(tmp_path / "lib")
    if lib is None:
        pytest.skip(why)
    db = str(tmp_path / "catalog.db")
    base = ["--db", db, "--config", "configs/quick.toml", "--set", "canonical_render.resolution=64",
            "--set", "canonical_render.samples=2"]
    assert main(base + ["catalog", "ingest", str(lib)]) == 0
    assert main(base + ["catalog", "render"]) == 0
    capsys.readouterr()
    assert main(base + ["catalog", "filter", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["objects"] == len(MODELS) and summary["missing_renders"] == 0
    catalog = open_catalog(db, data_dir="")
    try:
        with catalog.session() as s:
            folder = {o.id: Path(o.model_path).parent.name for o in s.scalars(select(CatalogObject))}
            status = {folder[o.id]: o.status for o in s.scalars(select(CatalogObject))}
            pairs = {}
            for f in s.scalars(select(Flag).where(Flag.pair_object_id.is_not(None))):
                pairs.setdefault(frozenset((folder[f.object_id], folder[f.pair_object_id])), []).append(f)
    finally:
        catalog.close()
    decide = sorted(sorted(p) for p, fs in pairs.items() if any(severity(f.kind, f.reason) == "decide" for f in fs))
    print(f"\nuntextured library: {summary['objects']} objects, excluded {summary['excluded']}, "
          f"pairs to decide {summary['to_decide_pairs']}: {decide}")
    assert summary["excluded"] == 0 and all(v == "active" for v in status.values()), status
    assert not any(f.kind in DUPLICATE_KINDS for fs in pairs.values() for f in fs)
    assert summary["to_decide_pairs"] <= 3, decide
    nut = pairs.get(frozenset(("Hex nut", "Hockey puck")), [])
    assert all(severity(f.kind, f.reason) == "info" for f in nut), [f.reason for f in nut]
