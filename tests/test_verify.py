"""The record of a scene's files, `mixcount verify`, and damaged scenes repaired by `compose` and left out
by `merge` by name.

Here the render is a stand-in (``FakeWorker`` from test_compose_orchestration, behind the real scene
task, finalise, record and merge); ``test_real_scene_damage_is_caught_and_repaired`` does the same on
scenes rendered by real bpy (the session's composed dataset, copied).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest
from test_compose_orchestration import FakeWorker, _pool

from mixcount.cli import main
from mixcount.config import load_config
from mixcount.dataset.manifest import DAMAGE_REPORT, DAMAGED_DIR, MANIFEST_NAME, check_scene, record_scene_files
from mixcount.dataset.verify import verify_dataset
from mixcount.run.compose import compose_scenes
from mixcount.run.local import LocalExecutor
from mixcount.run.scene_task import run_scene_task

PROJECT_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture()
def setup(tmp_path: Path):
    config = load_config(["quick"], values={"compose.seed": 200, "compose.split": "train"})
    return config, _pool(tmp_path), tmp_path / "out", tmp_path / "assets"


def compose(setup, n: int, calls: list[int], plan: Callable[[int], str] = lambda s: "ok"):
    config, pool, out, assets = setup
    runner = lambda task, _worker: run_scene_task(task, FakeWorker(task.spec, plan, calls))  # noqa: E731
    with LocalExecutor(1, runner=runner, recycle_after=0, settle_ahead=False) as executor:
        return compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=assets, n=n, executor=executor)


def scene_dirs(out: Path) -> list[Path]:
    return sorted(p for p in (out / "scenes").iterdir() if p.is_dir() and not p.name.startswith("."))


def tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def damage(scene: Path, how: str, name: str) -> None:
    path = scene / name
    if how == "delete":
        path.unlink()
    elif how == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    else:  # modify: same size, one byte changed (a bad sync; in a JSON file a digit, so it still parses)
        data = bytearray(path.read_bytes())
        k = len(data) // 2
        if path.suffix == ".json":
            k = next(i for i in range(k, len(data)) if chr(data[i]).isdigit())
            data[k] = ord("7") if data[k] != ord("7") else ord("3")
        else:
            data[k] ^= 0xFF
        path.write_bytes(bytes(data))


def test_record_lists_every_file_generically(tmp_path: Path) -> None:
    d = tmp_path / "scene_000001"
    (d / "exemplars").mkdir(parents=True)
    for name in ("rgb.png", "rgb_cam1.png", "coco.json", "exemplars/7_0.png", "metadata.json"):
        (d / name).write_bytes(name.encode() * 3)
    record = record_scene_files(d)
    assert sorted(record["files"]) == ["coco.json", "exemplars/7_0.png", "metadata.json", "rgb.png", "rgb_cam1.png"]
    assert record["files"]["rgb.png"]["size"] == len(b"rgb.png" * 3)
    assert check_scene(d, deep=True).ok
    (d / "notes.txt").write_text("mine")
    (d / "rgb_cam1.png").unlink()
    c = check_scene(d, deep=True)
    assert (c.missing, c.extra, c.damaged) == (["rgb_cam1.png"], ["notes.txt"], True)
    m = json.loads((d / MANIFEST_NAME).read_text())
    m["files"]["rgb.png"]["size"] += 1  # an edited record no longer matches its own digest
    (d / MANIFEST_NAME).write_text(json.dumps(m))
    assert "manifest.json is damaged" in (check_scene(d, deep=True).error or "")


def test_quick_check_hashes_only_files_whose_time_changed(tmp_path: Path) -> None:
    d = tmp_path / "scene_000002"
    d.mkdir()
    (d / "rgb.png").write_bytes(b"abcdef")
    record_scene_files(d)
    assert check_scene(d, deep=False).hashed_bytes == 0
    st = (d / "rgb.png").stat()
    (d / "rgb.png").write_bytes(b"abcdeX")  # same size
    os.utime(d / "rgb.png", ns=(st.st_atime_ns, st.st_mtime_ns))  # ... and the old time put back
    assert check_scene(d, deep=False).ok, "only a hash can see this one"
    assert check_scene(d, deep=True).changed == ["rgb.png (content differs from its record)"]
    os.utime(d / "rgb.png", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert check_scene(d, deep=False).changed == ["rgb.png (content differs from its record)"]


def test_deleted_truncated_and_modified_files_are_caught_and_repaired(setup, capsys) -> None:
    config, pool, out, assets = setup
    calls: list[int] = []
    assert compose(setup, 4, calls).written == 4
    scenes = scene_dirs(out)
    assert all((d / MANIFEST_NAME).is_file() for d in scenes)
    whole = verify_dataset(out)
    assert whole.problems == 0 and whole.sound == 4 and whole.hashed_bytes > 0
    originals = {d.name: tree(d) for d in scenes}

    damage(scenes[0], "delete", "rgb.png")
    damage(scenes[1], "truncate", "class.png")
    damage(scenes[2], "modify", "coco.json")
    (scenes[3] / "notes.txt").write_text("a user's note: extra, not damage")

    rc = main(["verify", str(out), "--json"])
    captured = capsys.readouterr()
    assert rc == 1
    report = json.loads(captured.out)
    assert report["damaged"] == 3 and report["problems"] >= 4
    lines = captured.err
    assert f"{scenes[0].name}: missing rgb.png" in lines
    assert f"{scenes[1].name}: changed class.png (size" in lines
    assert f"{scenes[2].name}: changed coco.json (content differs from its record)" in lines
    assert f"{scenes[3].name}: extra notes.txt" in lines
    assert "Traceback" not in lines

    # merge leaves the three damaged scenes out by name (exit 1) and merges the sound one
    rc = main(["merge", str(out), "--json"])
    captured = capsys.readouterr()
    assert rc == 1 and "Traceback" not in captured.err
    res = json.loads(captured.out)
    left_out = {line.split(":")[0] for line in res["damaged"]}
    assert {scenes[0].name, scenes[1].name} <= left_out <= {d.name for d in scenes[:3]}
    assert all(f"damaged scene left out: {name}" in captured.err for name in left_out)
    merged = json.loads((out / "annotations" / "instances_train.json").read_text())
    # a same-size edit of coco.json is beyond merge's cheap check (one stat per file; verify's hash sees
    # it): merge leaves it out only when it cannot read it as a scene's COCO
    assert {img["scene_id"] for img in merged["images"]} == {d.name for d in scenes} - left_out

    # compose sets the damaged scenes aside (nothing deleted) and renders those seeds again
    calls.clear()
    summary = compose(setup, 4, calls)
    assert summary.written == 4 and sorted(d["scene_id"] for d in summary.damaged) == [d.name for d in scenes[:3]]
    assert sorted(calls) == sorted(int(d.name.split("_")[1]) for d in scenes[:3])
    aside = sorted((out / "scenes" / DAMAGED_DIR).iterdir())
    assert [p.name.rsplit("-", 1)[0] for p in aside] == [d.name for d in scenes[:3]]
    for p in aside:
        sid = p.name.rsplit("-", 1)[0]
        kept = tree(p)
        report_json = json.loads(kept.pop(DAMAGE_REPORT))
        assert report_json["scene_id"] == sid and report_json["damaged"]
        want = dict(originals[sid])
        for name in set(want) - set(kept):
            assert name == "rgb.png" and sid == scenes[0].name  # the file the user deleted
        assert set(kept) <= set(want) | {"rgb.png"}
    assert verify_dataset(out).to_dict()["damaged"] == 0
    assert verify_dataset(out).lines() == [f"{scenes[3].name}: extra notes.txt"]
    merged = json.loads((out / "annotations" / "instances_train.json").read_text())
    assert len(merged["images"]) == 4


def test_a_deleted_metadata_json_is_damage_not_an_unfinished_scene(setup) -> None:
    """Without metadata.json a finished scene looks unfinished; its record says otherwise, so compose
    sets the folder aside instead of deleting it on its way to re-render the seed."""
    out = setup[2]
    compose(setup, 1, [])
    scene = scene_dirs(out)[0]
    (scene / "metadata.json").unlink()
    before = tree(scene)
    res = main(["merge", str(out)])
    assert res == 1  # merge names it instead of leaving it out in silence
    summary = compose(setup, 1, calls := [])
    assert calls == [int(scene.name.split("_")[1])] and summary.damaged[0]["problems"] == "missing metadata.json"
    (aside,) = (out / "scenes" / DAMAGED_DIR).iterdir()
    kept = tree(aside)
    kept.pop(DAMAGE_REPORT)
    assert kept == before


def test_merge_of_an_unreadable_coco_is_undone_and_named(tmp_path: Path, capsys) -> None:
    """A coco.json that is valid JSON of the recorded size but not a scene's COCO: what the split had
    written for it is cut back, so the merged file holds only whole scenes."""
    from test_merge import _scene

    for k in range(3):
        record_scene_files(_scene(tmp_path, k, "train", n_ann=k + 1))
    bad = tmp_path / "scenes" / "scene_000001" / "coco.json"
    coco = json.loads(bad.read_text())
    coco["images"][0]["exemplars"][0]["annotation_ids"] = [99]  # fails half-way through the scene
    text = json.dumps(coco)
    bad.write_text(text)
    record_scene_files(bad.parent)  # recorded as is: only reading it as COCO can fail
    rc = main(["merge", str(tmp_path)])
    captured = capsys.readouterr()
    assert rc == 1 and "Traceback" not in captured.err
    assert "scene_000001: coco.json cannot be merged (KeyError: 99)" in captured.err
    merged = json.loads((tmp_path / "annotations" / "instances_train.json").read_text())
    assert [i["scene_id"] for i in merged["images"]] == ["scene_000000", "scene_000002"]
    assert [a["id"] for a in merged["annotations"]] == [1, 2, 3, 4]
    assert {a["scene_id"] for a in merged["annotations"]} == {"scene_000000", "scene_000002"}


def test_verify_checks_the_merged_files_against_the_scenes(setup, capsys) -> None:
    out = setup[2]
    compose(setup, 2, [])
    path = out / "annotations" / "instances_train.json"
    merged = json.loads(path.read_text())
    dropped = merged["images"].pop()["scene_id"]
    merged["annotations"] = [a for a in merged["annotations"] if a["scene_id"] != dropped]
    path.write_text(json.dumps(merged))
    report = verify_dataset(out)
    assert report.scene_problems == []
    assert report.lines() == [f"annotations/instances_train.json: lacks finished scene {dropped} (run `mixcount merge`)"]
    assert main(["merge", str(out)]) == 0
    capsys.readouterr()
    assert verify_dataset(out).problems == 0


def test_verify_from_the_console_script(setup) -> None:
    out = setup[2]
    compose(setup, 1, [])
    scene = scene_dirs(out)[0]
    (scene / "rgb.png").unlink()
    res = subprocess.run([sys.executable, "-m", "mixcount", "verify", str(out), "--json"], cwd=PROJECT_ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 1 and "Traceback" not in res.stderr
    assert f"{scene.name}: missing rgb.png" in res.stderr
    assert f"lists image scenes/{scene.name}/rgb.png, which does not exist" in res.stderr
    assert json.loads(res.stdout)["damaged"] == 1
    missing = subprocess.run([sys.executable, "-m", "mixcount", "verify", str(out / "nowhere")], cwd=PROJECT_ROOT,
                             capture_output=True, text=True, timeout=120)
    assert missing.returncode == 2 and missing.stderr.strip().endswith("holds no scenes/ folder: nothing to verify")


@pytest.mark.blender
def test_real_scene_damage_is_caught_and_repaired(composed_dataset: Path, tmp_path: Path, capsys) -> None:
    """Scenes rendered by real bpy (the session's composed dataset, copied): a deleted rgb.png, a
    truncated depth pass and a modified coco.json are caught by verify and repaired by the same compose."""
    root = tmp_path / "copy"
    shutil.copytree(composed_dataset, root / "out", symlinks=True)
    out = root / "out"
    db = composed_dataset.parent / "catalog.db"
    assert main(["verify", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    a, b = scene_dirs(out)
    depth = next(p.name for p in a.iterdir() if p.name.startswith("depth"))
    originals = {a.name: tree(a), b.name: tree(b)}
    damage(a, "delete", "rgb.png")
    damage(a, "truncate", depth)
    damage(b, "modify", "coco.json")
    assert main(["verify", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"{a.name}: missing rgb.png; changed {depth} (size" in err
    assert f"{b.name}: changed coco.json (content differs from its record)" in err
    rc = main(["--db", str(db), "--config", "quick", "--set", "scene.n_objects=[16,24]", "compose", "--n", "2",
               "--split", "train", "--seed", "5", "--resolution", "96", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "2 damaged set aside and rendered again" in captured.out and "Traceback" not in captured.err
    assert main(["verify", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    aside = sorted((out / "scenes" / DAMAGED_DIR).iterdir())
    assert [p.name.rsplit("-", 1)[0] for p in aside] == [a.name, b.name]
    kept_b = tree(aside[1])
    kept_b.pop(DAMAGE_REPORT)
    assert set(kept_b) == set(originals[b.name])  # every file kept, the modified one as it was found
    assert kept_b["coco.json"] != originals[b.name]["coco.json"] and kept_b["rgb.png"] == originals[b.name]["rgb.png"]
    assert sorted(p.name for p in scene_dirs(out)) == [a.name, b.name]


def test_a_scene_without_a_record_is_checked_for_the_files_it_names(tmp_path: Path, capsys) -> None:
    """Scenes written before records existed: verify calls them unproven (exit 1), merge and compose's
    check still see a file their coco.json names go missing (the issue's rgb.png case, without a
    traceback from the preview)."""
    from test_merge import _scene

    for k in range(2):
        _scene(tmp_path, k, "train", n_ann=2)
    report = verify_dataset(tmp_path)
    assert [c.unrecorded for c in report.scene_problems] == [True, True]
    assert report.lines()[0].startswith("scene_000000: no manifest.json (written before mixcount recorded")
    (tmp_path / "scenes" / "scene_000001" / "rgb.png").unlink()
    assert check_scene(tmp_path / "scenes" / "scene_000001", deep=False).missing == ["rgb.png"]
    assert main(["merge", str(tmp_path)]) == 1
    captured = capsys.readouterr()
    assert "damaged scene left out: scene_000001: missing rgb.png" in captured.err and "Traceback" not in captured.err
    merged = json.loads((tmp_path / "annotations" / "instances_train.json").read_text())
    assert [i["scene_id"] for i in merged["images"]] == ["scene_000000"]
    assert (tmp_path / "preview.png").is_file()
