"""The catalog CLI end to end: demo-library -> catalog ingest -> list / show, and the stable JSON shape
that later issues and tests rely on (docs/catalog-json.md)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CaptionSet, CatalogObject, Flag, Split
from mixcount.cli import main

PROJECT_ROOT = Path(__file__).resolve().parent.parent
RECORD_KEYS = {
    "id", "name", "category", "status", "error", "flags", "captions", "split", "source", "source_id",
    "model_path", "content_hash", "geometry_hash", "source_units", "source_up_axis", "dims_m", "vertex_count",
    "face_count", "watertight", "volume_m3", "area_m2", "textured", "appearance", "collision_path",
    "collision_face_count", "license", "metadata", "ingest_run_id", "created_at", "updated_at",
}


def cli(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture
def demo_db(tmp_path, capsys):
    lib = tmp_path / "demo"
    db = str(tmp_path / "catalog.db")
    code, out, _ = cli(capsys, "demo-library", str(lib), "--seed", "3", "--n", "12", "--json")
    assert code == 0
    expected = json.loads(out)
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(lib), "--json", "--workers", "2")
    assert code == 0, err
    summary = json.loads(out)
    assert (summary["new"], summary["broken"]) == (expected["active"], expected["broken"])
    return db, lib, expected


def test_list_summary_and_filters(demo_db, capsys):
    db, lib, expected = demo_db
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--summary", "--json")
    summary = json.loads(out)
    assert summary["total"] == expected["total"]
    assert summary["by_status"] == {"active": expected["active"], "excluded": 0, "broken": expected["broken"]}
    assert sorted(summary["by_category"]) == sorted(set(expected["categories"]) | {"ball", "can"})
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--summary")
    assert f"{expected['total']} objects: {expected['active']} active, 0 excluded, {expected['broken']} broken" in out

    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--json", "--status", "broken")
    broken = json.loads(out)
    assert len(broken) == expected["broken"]
    assert all(r["status"] == "broken" and r["error"] and r["dims_m"] is None for r in broken)
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--json", "--category", "Marker")
    markers = json.loads(out)
    assert markers and {r["category"] for r in markers} == {"marker"}
    code, _, err = cli(capsys, "--db", db, "catalog", "list", "--status", "sleeping")
    assert code != 0 and "unknown status" in err


def test_json_shape_and_later_fields(demo_db, capsys):
    db, lib, _ = demo_db
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--json")
    records = json.loads(out)
    assert isinstance(records, list) and records
    for r in records:
        assert RECORD_KEYS <= set(r), RECORD_KEYS - set(r)
        assert r["status"] in ("active", "excluded", "broken")
        assert r["flags"] == [] and r["captions"] is None and r["split"] is None
    active = [r for r in records if r["status"] == "active"]
    a, b = active[0], active[1]
    assert len(a["dims_m"]) == 3 and all(0.005 < d < 0.4 for d in a["dims_m"])
    # later issues fill flags, captions and split: the same shape carries them
    cat = open_catalog(db, data_dir="")
    with cat.session() as s:
        s.add(Flag(object_id=a["id"], kind="exact_duplicate", score=1.0, reason="same bytes", pair_object_id=b["id"]))
        s.add(CaptionSet(object_id=a["id"], captioner="stub", provider="stub", model="m", prompt_version="v1",
                         short="ball", concise="red ball", detailed="a small red ball", response_hash="h", active=True))
        s.add(Split(object_id=a["id"], split="test", method="random", seed=0))
        s.get(CatalogObject, b["id"]).status = "excluded"
        s.commit()
    cat.close()
    code, out, _ = cli(capsys, "--db", db, "catalog", "show", str(a["id"]), "--json")
    rec = json.loads(out)
    assert rec["flags"] == [{"kind": "exact_duplicate", "score": 1.0, "reason": "same bytes", "pair": b["id"],
                             "pair_name": b["name"]}]
    assert rec["captions"] == {"short": "ball", "concise": "red ball", "detailed": "a small red ball"}
    assert rec["split"] == "test" and rec["split_detail"]["method"] == "random"
    assert rec["caption_sets"][0]["active"] is True and rec["reviews"] == [] and rec["renders"] == []
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--json", "--status", "excluded")
    assert [r["id"] for r in json.loads(out)] == [b["id"]]
    code, out, _ = cli(capsys, "--db", db, "catalog", "show", a["name"])
    assert code == 0 and a["name"] in out and "exact_duplicate" in out
    code, _, err = cli(capsys, "--db", db, "catalog", "show", "999999")
    assert code != 0 and "no catalog object" in err


@pytest.mark.slow
def test_make_demo_lines_match_the_generator(tmp_path):
    """What `make demo` runs, through the installed console script, on the full demo library."""
    exe = shutil.which("mixcount", path=str(PROJECT_ROOT / ".venv" / "bin")) or shutil.which("mixcount")
    base = [exe] if exe else [sys.executable, "-m", "mixcount"]
    env = {**os.environ, "COLUMNS": "200"}
    lib, db = tmp_path / "demo", tmp_path / "catalog.db"

    def run(*args: str) -> subprocess.CompletedProcess:
        res = subprocess.run(base + ["--db", str(db), *args], cwd=tmp_path, capture_output=True, text=True,
                             env=env, timeout=300)
        assert res.returncode == 0, res.stderr
        return res

    run("demo-library", str(lib))
    truth = json.loads((lib / "ground_truth.json").read_text())
    exp = truth["expected"]
    res = run("catalog", "ingest", str(lib))
    assert f"ingested {exp['total']} objects: {exp['active']} new, 0 unchanged, 0 updated, {exp['broken']} broken" in res.stdout
    res = run("catalog", "list", "--summary")
    assert f"{exp['total']} objects: {exp['active']} active, 0 excluded, {exp['broken']} broken" in res.stdout
    assert len(truth["categories"]) >= 10
    res = run("catalog", "ingest", str(lib))
    assert f"0 new, {exp['active']} unchanged, 0 updated, {exp['broken']} broken" in res.stdout
