"""`mixcount compose --dry-run` and `--stage-only` on a real (demo) catalog."""

from __future__ import annotations

import json

import pytest

from mixcount.cli import main


@pytest.fixture(scope="module")
def demo_db(tmp_path_factory, demo_catalog_copy):
    """A copy of the session's 16-object demo catalog (build_demo_catalog's default size)."""
    return demo_catalog_copy(tmp_path_factory.mktemp("compose"), 16)


def test_dry_run_prints_plan_and_writes_nothing(demo_db, capsys, tmp_path):
    db = str(demo_db / "catalog.db")
    rc = main(["--db", db, "--config", "quick", "compose", "--dry-run", "--n", "3", "--seed", "10",
               "--split", "train", "--out", str(tmp_path / "out"), "--json"])
    assert rc == 0
    plan = json.loads(capsys.readouterr().out)
    assert [p["scene_id"] for p in plan] == ["scene_000010", "scene_000011", "scene_000012"]
    for p in plan:
        assert 6 <= p["n_counted"] <= 14 and 2 <= len(p["classes"]) <= 3
        assert sum(c["count"] for c in p["classes"]) == p["n_counted"]
        assert p["environment"] == "hdri" and p["environment_map"].endswith(".exr")  # bpy's bundled HDRIs
        for c in p["classes"]:
            assert 0.45 <= c["size_m"] <= 1.2 and c["size_real_m"] == pytest.approx(c["size_m"] / 10, abs=1e-4)
    assert not (tmp_path / "out").exists()
    # same seeds, same plan
    main(["--db", db, "--config", "quick", "compose", "--dry-run", "--n", "3", "--seed", "10", "--split", "train", "--json"])
    assert json.loads(capsys.readouterr().out) == plan


def test_stage_only_writes_stages(demo_db, capsys, tmp_path):
    db = str(demo_db / "catalog.db")
    rc = main(["--db", db, "--config", "quick", "--set", "compose.split=train", "compose", "--stage-only",
               "--n", "2", "--out", str(tmp_path / "out"), "--json"])
    assert rc == 0
    stages = json.loads(capsys.readouterr().out)["stages"]
    assert [p.split("/")[-2] for p in stages] == ["scene_000000", "scene_000001"]
    for p in stages:
        text = open(p).read()
        assert text.startswith("#usda 1.0") and '"mixcount:role"' not in text  # nested customData only


def test_empty_split_is_a_clear_error(demo_db, capsys):
    rc = main(["--db", str(demo_db / "catalog.db"), "compose", "--dry-run", "--split", "test"])
    assert rc == 2
    assert "no active objects in split 'test'" in capsys.readouterr().err


def test_dry_run_shows_the_ids_the_run_writes_and_what_is_missing(demo_db, capsys, tmp_path):
    """Issue 56: seeds an earlier run threw away are passed over in the plan as in the run, and the objects'
    missing captions and renders are said once with the command that fixes them."""
    rejected = tmp_path / "out" / "scenes" / ".rejected"
    rejected.mkdir(parents=True)
    (rejected / "scene_000010.json").write_text("{}")
    rc = main(["--db", str(demo_db / "catalog.db"), "--config", "quick", "compose", "--dry-run", "--n", "2",
               "--seed", "10", "--split", "train", "--out", str(tmp_path / "out"), "--json"])
    captured = capsys.readouterr()
    assert rc == 0
    assert [p["scene_id"] for p in json.loads(captured.out)] == ["scene_000011", "scene_000012"]
    err = " ".join(captured.err.split())
    assert "thrown away by an earlier run" in err and "scene_000010" in err
    assert err.count("never captioned") == 1 and "mixcount catalog caption" in err
    assert err.count("no canonical render") == 1 and "mixcount catalog render" in err
