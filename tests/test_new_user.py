"""What a new user trips over (issue 35, items 5-9), each from the user's side: the command, what it prints
(stdout: the result; stderr: messages), and what is on disk after.

The library is shaped like a person's own: loose files named by hand (``red_block.glb``, ``big ball.stl``,
``coffee-mug-02.ply``), models in formats ingest does not read beside them, a folder with nothing in it.
No engine is needed: these commands stop before any render.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import trimesh

from mixcount.cli import main
from mixcount.config import load_config

LOOSE = {"red_block.glb": "block", "big ball.stl": "ball", "coffee-mug-02.ply": "mug"}


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def flat(text: str) -> str:
    """Help text with its line wrapping undone."""
    return " ".join(text.split())


def own_library(root: Path) -> Path:
    """Three loose model files named by a person, plus an FBX and a COLLADA file and a note."""
    root.mkdir(parents=True)
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(root / "red_block.glb")
    trimesh.creation.icosphere(subdivisions=2, radius=0.04).export(root / "big ball.stl")
    trimesh.creation.cylinder(radius=0.04, height=0.1).export(root / "coffee-mug-02.ply")
    (root / "chair.fbx").write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00")
    (root / "lamp.dae").write_text('<?xml version="1.0"?><COLLADA version="1.4.1"/>')
    (root / "notes.txt").write_text("where the models came from")
    return root


@pytest.fixture
def ingested(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[str, Path]:
    lib = own_library(tmp_path / "lib")
    db = str(tmp_path / "cat" / "catalog.db")
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(lib), "--workers", "1")
    assert code == 0, err
    return db, lib


# ---------------------------------------------------------------------------------------- 5. ingest


def test_ingest_names_the_files_it_skips_and_ingests_the_rest(tmp_path, capsys):
    lib = own_library(tmp_path / "lib")
    db = str(tmp_path / "catalog.db")
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(lib), "--workers", "1")
    assert code == 0, err
    assert "ingested 3 objects: 3 new" in out and "skipped 2 file(s)" in out
    assert "skipped 2 file(s) in formats ingest does not read (1 .dae COLLADA, 1 .fbx Autodesk FBX)" in err
    assert f"skipped {lib / 'chair.fbx'}: Autodesk FBX (.fbx) is not a format ingest reads" in err
    assert f"skipped {lib / 'lamp.dae'}" in err and "notes.txt" not in err  # only model formats are named
    code, out, err = cli(capsys, "--db", db, "catalog", "ingest", str(lib), "--json")
    summary = json.loads(out)
    assert summary["unchanged"] == 3 and sorted(Path(s["path"]).name for s in summary["skipped"]) == ["chair.fbx", "lamp.dae"]


def test_loose_files_are_categorised_by_their_noun(ingested, capsys):
    db, _ = ingested
    code, out, _ = cli(capsys, "--db", db, "catalog", "list", "--json")
    assert code == 0
    assert {o["name"]: o["category"] for o in json.loads(out)} == {Path(k).stem: v for k, v in LOOSE.items()}


def test_ingest_of_an_empty_folder_is_an_error_and_creates_nothing(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    db = tmp_path / "cat" / "catalog.db"
    code, out, err = cli(capsys, "--db", str(db), "catalog", "ingest", str(empty))
    assert code == 2 and out == ""
    assert f"error: no model file to ingest under {empty}; ingest reads .glb" in err and "nothing was ingested" in err
    assert not db.exists() and not db.parent.exists()
    only_fbx = tmp_path / "fbx"
    only_fbx.mkdir()
    (only_fbx / "chair.fbx").write_bytes(b"Kaydara FBX Binary  \x00")
    code, _, err = cli(capsys, "--db", str(db), "catalog", "ingest", str(only_fbx))
    assert code == 2 and "only 1 file(s) in formats ingest does not read (.fbx)" in err and not db.exists()


# ---------------------------------------------------------------------------------------- 6. config and help


def test_config_given_as_a_repository_path_works_from_any_folder(ingested, tmp_path, capsys, monkeypatch):
    db, _ = ingested
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    for given in ("configs/quick.toml", "quick"):
        code, out, err = cli(capsys, "--db", db, "--config", given, "catalog", "list", "--summary", "--json")
        assert code == 0, err
        assert json.loads(out)["total"] == 3
    code, _, err = cli(capsys, "--db", db, "--config", "configs/nothere.toml", "catalog", "list")
    assert code == 2 and "config file not found: configs/nothere.toml" in err


def test_help_examples_name_known_keys_and_defaults_show(capsys):
    code, out, _ = cli(capsys, "--help")
    assert code == 0
    text = flat(out)
    examples = re.findall(r"--set ([a-z_]+\.[a-z_]+=[^\s;]+)", text)
    assert examples, text
    load_config([], examples)  # an unknown key would raise
    assert "[default: catalog/catalog.db]" in text and "quick" in text
    code, out, _ = cli(capsys, "catalog", "split", "--help")
    assert "Seed of the random part [default: split.seed]." in flat(out)
    code, out, _ = cli(capsys, "catalog", "ingest", "--help")
    assert "Mesh-analysis processes [default: ingest.workers]." in flat(out)


def test_unknown_set_key_names_the_nearest(ingested, capsys):
    db, _ = ingested
    code, out, err = cli(capsys, "--db", db, "--set", "compose.sample=3", "catalog", "list")
    assert code == 2 and out == ""
    assert "unknown config key 'compose.sample' in override 'compose.sample=3'; did you mean 'compose.samples'?" in err
    code, _, err = cli(capsys, "--db", db, "--set", "scene.n_objects_max=50", "catalog", "list")
    assert "did you mean 'scene.n_objects'?" in err


# ---------------------------------------------------------------------------------------- 7. baseline


def _dataset(root: Path) -> Path:
    from test_evaluate import make_coco

    (root / "annotations").mkdir(parents=True)
    (root / "annotations" / "instances_train.json").write_text(json.dumps(make_coco({(1, 10): (7, 0)})))
    (root / "annotations" / "instances_test.json").write_text(json.dumps(make_coco()))
    return root


def test_baseline_reference_is_the_training_split_never_the_evaluated_one(tmp_path, capsys):
    ds = _dataset(tmp_path / "ds")
    pred = tmp_path / "mean.json"
    code, out, err = cli(capsys, "baseline", "--gt", str(ds), "--split", "test", "--reference", str(ds),
                         "--out", str(pred))
    assert code == 0, err
    doc = json.loads(pred.read_text())
    assert {r["count"] for r in doc["predictions"]} == {7.0}  # train's mean, not test's own
    assert doc["reference"].endswith("instances_train.json") and "mean count 7.00" in out
    code, out, err = cli(capsys, "baseline", "--gt", str(ds), "--split", "test", "--reference", str(ds),
                         "--reference-split", "test", "--out", str(tmp_path / "leak.json"))
    assert code == 2 and "the very split being evaluated" in err and not (tmp_path / "leak.json").exists()
    code, out, err = cli(capsys, "baseline", "--gt", str(ds), "--split", "test", "--out", str(tmp_path / "own.json"))
    assert code == 0 and "warning: no --reference" in err and "knows the answer" in err


# ---------------------------------------------------------------------------------------- 8. small libraries


def test_split_of_a_small_library_warns_about_an_empty_split(ingested, capsys):
    db, _ = ingested
    code, out, err = cli(capsys, "--db", db, "catalog", "split")
    assert code == 0, err
    assert "warning: split 'val' has 0 objects (target 15% of 3 active objects): `mixcount compose --split val` " \
           "will find nothing" in flat(err)
    code, out, err = cli(capsys, "--db", db, "catalog", "split", "--json")
    summary = json.loads(out)
    assert summary["totals"]["val"] == 0 and len(summary["warnings"]) == 1  # 3 objects at 70/15/15


def test_compose_of_an_empty_split_leaves_nothing_behind(ingested, tmp_path, capsys):
    db, _ = ingested
    assert cli(capsys, "--db", db, "catalog", "split")[0] == 0
    target = tmp_path / "dataset"
    code, out, err = cli(capsys, "--db", db, "compose", "--split", "val", "--out", str(target))
    assert code == 2 and out == ""
    assert not target.exists()  # no empty scenes/ left behind
    assert "no active objects in split 'val' (active objects per split: train" in err and "nothing was written" in err


def test_read_commands_do_not_create_a_catalog(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MIXCOUNT_DB", raising=False)
    for args in (["catalog", "list"], ["catalog", "show", "1"], ["compose", "--dry-run"], ["catalog", "split"]):
        code, out, err = cli(capsys, *args)
        assert code == 2 and out == "", args
        assert f"error: no catalog at {tmp_path / 'catalog' / 'catalog.db'} (from the default catalog/catalog.db)" in err
    assert not (tmp_path / "catalog").exists()
    code, _, err = cli(capsys, "--db", str(tmp_path / "mine.db"), "catalog", "list")
    assert code == 2 and "(from --db)" in err and not (tmp_path / "mine.db").exists()


# ---------------------------------------------------------------------------------------- 9. messages


def test_a_repeated_prediction_is_blamed_on_the_prediction_file(tmp_path, capsys):
    ds = _dataset(tmp_path / "ds")
    pred = tmp_path / "pred.json"
    pred.write_text(json.dumps([{"image_id": 1, "category_id": 10, "count": 4},
                                {"image_id": 2, "category_id": 11, "count": 1},
                                {"image_id": 1, "category_id": 10, "count": 5}]))
    code, out, err = cli(capsys, "evaluate", "--gt", str(ds), "--pred", str(pred))
    assert code == 2 and out == ""
    assert f"{pred}: rows 0 and 2 both predict image_id 1, category_id 10" in err
    assert "instances_test.json" not in err
    pred.write_text(json.dumps([{"image_id": 1, "category_id": 10, "count": 3, "points": [[1, 2]]}]))
    code, _, err = cli(capsys, "evaluate", "--gt", str(ds), "--pred", str(pred))
    assert code == 2 and "row 0: its counts disagree ('count' 3 vs 1 point in 'points')" in err


def test_every_command_prints_its_result_on_stdout_and_json_only_with_json(ingested, tmp_path, capsys):
    """Without --json stdout holds a readable summary (no JSON, no Python dict, no None); with --json it
    holds exactly one JSON document; messages stay on stderr."""
    from typer.main import get_command

    from mixcount.cli import app

    db, lib = ingested
    ds = _dataset(tmp_path / "ds")
    pred = tmp_path / "pred.json"
    runs = {
        "ingest": ["--db", db, "catalog", "ingest", str(lib)],
        "list": ["--db", db, "catalog", "list", "--summary"],
        "show": ["--db", db, "catalog", "show", "1"],
        "demo-library": ["demo-library", str(tmp_path / "demo"), "--n", "2"],
        "baseline": ["baseline", "--gt", str(ds), "--reference", str(ds), "--out", str(pred)],
        "evaluate": ["evaluate", "--gt", str(ds), "--pred", str(pred)],
        "stats": ["stats", str(ds), "--no-plots"],
        "caption": ["--db", db, "catalog", "caption"],
        "split": ["--db", db, "catalog", "split"],
        "dry-run": ["--db", db, "--config", "quick", "compose", "--dry-run", "--split", "train", "--n", "1"],
    }
    for name, args in runs.items():
        code, out, err = cli(capsys, *args)
        assert code == 0, (name, err)
        assert out.strip(), name
        assert not out.lstrip().startswith(("{", "[")), (name, out[:200])
        assert "{'" not in out and " None" not in out, (name, out)
        code, out, err = cli(capsys, *args, "--json")
        assert code == 0, (name, err)
        json.loads(out)  # one JSON document, nothing else
    # and every command has the option
    root = get_command(app)
    missing = []
    for group in (root, root.commands["catalog"], root.commands["catalog"].commands["review"]):  # type: ignore[attr-defined]
        for cname, command in group.commands.items():  # type: ignore[attr-defined]
            if hasattr(command, "commands"):
                continue
            if not any("--json" in p.opts for p in command.params):
                missing.append(cname)
    assert missing == []
