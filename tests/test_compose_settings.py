"""A dataset holds one configuration (issue 35, item 2): ``compose`` into a folder whose scenes were made
with other settings is refused with the differing keys named and nothing written; ``--mixed-settings``
adds the scenes and dataset.json says which scenes hold which settings; the summary line counts new
scenes and scenes already there truthfully; another split or seed into the same folder is not a change
of settings. Real demo catalog, real one-scene renders at 32 px."""

from __future__ import annotations

import json

import pytest
from test_usd_stage import build_demo_catalog

from mixcount.cli import main

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def compose(capsys, db: str, out: str, *extra: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(["--db", db, "--config", "quick", "--set", "scene.n_objects=[6,10]", "compose", "--n", "1",
                 "--split", "train", "--samples", "1", "--out", out, *extra])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def snapshot(out) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and "logs" not in p.parts}


def test_compose_refuses_other_settings_and_records_mixed_ones(tmp_path, capsys):
    build_demo_catalog(tmp_path, n_objects=8).close()
    db, out = str(tmp_path / "catalog.db"), tmp_path / "out"

    code, stdout, err = compose(capsys, db, str(out), "--resolution", "32")
    assert code == 0, err
    assert "wrote 1 new scene(s) (0 already there" in stdout + err

    # the same command again: nothing new, and the line says so
    code, stdout, err = compose(capsys, db, str(out), "--resolution", "32")
    assert code == 0, err
    assert "wrote 0 new scene(s) (1 already there" in stdout + err

    # another resolution: refused, the differing key named with both values, nothing written
    before = snapshot(out)
    code, stdout, err = compose(capsys, db, str(out), "--resolution", "48", "--seed", "7")
    assert code != 0
    assert "compose.resolution 32 there, 48 now" in err and "--mixed-settings" in err and "new --out" in err
    assert snapshot(out) == before

    # explicitly mixed: the scene is added, and the dataset says which scene holds which settings
    code, stdout, err = compose(capsys, db, str(out), "--resolution", "48", "--seed", "7", "--mixed-settings")
    assert code == 0, err
    assert "wrote 1 new scene(s) (0 already there" in stdout + err
    dataset = json.loads((out / "dataset.json").read_text())
    variants = {v["id"]: v["settings"] for v in dataset["settings_variants"]}
    assert variants[1]["compose.resolution"] == 32 and variants[2]["compose.resolution"] == 48
    by_scene = {s["scene_id"]: s["settings_id"] for s in dataset["scenes"]}
    assert by_scene == {"scene_000000": 1, "scene_000007": 2}
    widths = {json.loads((out / "scenes" / sid / "coco.json").read_text())["images"][0]["width"]: variants[v]
              for sid, v in by_scene.items()}
    assert {w: v["compose.resolution"] for w, v in widths.items()} == {32: 32, 48: 48}

    # once mixed, a run with either recorded setting is accepted without the flag
    code, stdout, err = compose(capsys, db, str(out), "--resolution", "32", "--seed", "20")
    assert code == 0, err
    assert json.loads((out / "dataset.json").read_text())["scenes"][-1]["settings_id"] == 1
