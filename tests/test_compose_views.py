"""``compose --n N --views K``: N piles with K more views each, in one pass (issue 38).

Real bpy composes on a copy of the 12-object demo catalog at 48 px, 1 sample, from the command line:
what it prints, what is on disk (one COCO image per view, the same files ``mixcount render --views``
writes), one instance id per object in every view under both annotation rules, and one pass (the
worker's log of the scene's request shows one import of its stage and every view's RGB render). That
the one-pass output equals ``compose`` then ``render --views`` pixel for pixel was checked by hand
(docs/blender.md); a count target with the all-cameras rule is refused before anything is written."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from PIL import Image

from mixcount.cli import main

BASE = ["--config", "quick", "--set", "scene.n_objects=[16,24]"]


def _compose(root: Path, out: Path, *args: str) -> int:
    return main(["--db", str(root / "catalog.db"), *BASE, "compose", "--n", "1", "--split", "train", "--seed", "5",
                 "--samples", "1", "--out", str(out), *args])


def _ids_by_view(d: Path, meta: dict) -> list[set[int]]:
    coco = json.loads((d / "coco.json").read_text())
    return [{a["instance_id"] for a in coco["annotations"] if a["image_id"] == k + 1} for k in range(len(meta["cameras"]))]


@pytest.mark.blender
def test_compose_views_writes_k_more_views_per_scene_in_one_pass(
        tmp_path: Path, demo_catalog_copy: Callable[[Path, int], Path], capsys: pytest.CaptureFixture[str]) -> None:
    root = demo_catalog_copy(tmp_path / "cat", 12)
    out = tmp_path / "out"
    capsys.readouterr()
    assert _compose(root, out, "--resolution", "48", "--views", "2") == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("wrote 1 new scene(s)")
    assert printed[-1] == ("views: each scene's own camera(s) and 2 by the paper's camera rule, rendered in its one "
                           "worker pass (annotation rule all_cameras)")
    (d,) = sorted((out / "scenes").glob("scene_*"))
    meta = json.loads((d / "metadata.json").read_text())
    n_views = len(meta["cameras"])
    assert n_views == 3 and meta["more_views"]["views"] == 3 and meta["more_views"]["own_views"] == 1
    assert [c["framing"]["rule"] for c in meta["cameras"][1:]] == ["paper camera rule (rerender)"] * 2
    for name in ("rgb", "instance", "class", "depth", "normal"):  # the files `mixcount render --views` writes
        for suffix in ("", "_cam_1", "_cam_2"):
            assert (d / f"{name}{suffix}.png").is_file(), f"{name}{suffix}.png"
    for suffix in ("_cam_1", "_cam_2"):
        assert np.array(Image.open(d / f"instance{suffix}.png")).shape == (48, 48)
    # the paper's rule over every view: each view annotates the same kept objects, under one id each
    kept = {o["instance_id"]: o["category_id"] for o in meta["objects"] if o["status"] == "kept"}
    views = _ids_by_view(d, meta)
    assert views[0] and all(v == set(kept) for v in views)
    coco = json.loads((d / "coco.json").read_text())
    assert all(kept[a["instance_id"]] == a["category_id"] for a in coco["annotations"])
    for k, suffix in enumerate(("", "_cam_1", "_cam_2")):
        ids = set(np.unique(np.array(Image.open(d / f"instance{suffix}.png"))).tolist()) - {0}
        assert ids == views[k]
    # one pass: physics ran once, and the worker's one request for the scene imported its stage once and
    # rendered every view's RGB (the log holds the last request's output; no settled.usda was read)
    assert meta["timings"]["worker.physics"] > 0 and meta["timings"]["worker.import"] > 0
    log = next(p for p in (out / "logs").glob("mixcount-worker0-*.log") if "settle" not in p.name).read_text()
    assert len([ln for ln in log.splitlines() if "USD import of" in ln and ln.rstrip().endswith("ms")
                and "/scene.usda'" in ln]) == 1
    assert "settled.usda" not in log
    assert all(f"rgb{s}.png" in log for s in ("", "_cam_1", "_cam_2"))
    merged = json.loads((out / "annotations" / "instances_train.json").read_text())
    assert len(merged["images"]) == 3
    assert main(["verify", str(out)]) == 0


@pytest.mark.blender
def test_compose_orbit_per_view_keeps_one_id_per_object(
        tmp_path: Path, demo_catalog_copy: Callable[[Path, int], Path]) -> None:
    root = demo_catalog_copy(tmp_path / "cat", 12)
    out = tmp_path / "out"
    assert _compose(root, out, "--resolution", "48", "--trajectory", "orbit", "--frames", "3", "--rule", "per_view") == 0
    (d,) = sorted((out / "scenes").glob("scene_*"))
    meta = json.loads((d / "metadata.json").read_text())
    assert meta["more_views"]["rule"] == "per_view" and len(meta["cameras"]) == 4
    assert [c["framing"]["frame"] for c in meta["cameras"][1:]] == [0, 1, 2]
    kept = {o["instance_id"]: o["category_id"] for o in meta["objects"] if o["status"] == "kept"}
    views = _ids_by_view(d, meta)
    assert all(v <= set(kept) for v in views) and any(views[1:])
    for k in range(1, 4):  # each view's map holds exactly the objects it annotates, under their one id
        ids = set(np.unique(np.array(Image.open(d / f"instance_cam_{k}.png"))).tolist()) - {0}
        assert ids == views[k]
    coco = json.loads((d / "coco.json").read_text())
    assert all(kept[a["instance_id"]] == a["category_id"] for a in coco["annotations"])


def test_views_with_a_count_target_under_the_all_cameras_rule_are_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from mixcount.config import load_config
    from mixcount.errors import CompositionError
    from mixcount.run.compose import compose_scenes

    cfg = load_config(["quick"], ["rerender.new_views=2", "scene.count_target=uniform:3-5"])
    out = tmp_path / "out"
    with pytest.raises(CompositionError, match="--rule per_view"):
        compose_scenes(pool=[type("Obj", (), {"split": "train"})()], config=cfg, out_dir=out, assets_dir=tmp_path, n=1)
    assert not out.exists()
    per_view = load_config(["quick"], ["rerender.new_views=2", "rerender.annotation_rule=per_view",
                                       "scene.count_target=uniform:3-5"])
    from mixcount.run.compose import more_views_of

    more = more_views_of(per_view)
    assert more is not None and more.rule == "per_view" and more.plan.new_views == 2
    assert more_views_of(load_config(["quick"], [])) is None  # no views: compose as before


def test_more_views_round_trip_through_the_scene_request() -> None:
    from mixcount.config import load_config
    from mixcount.worker.contract import MoreViews, SceneOutputs, SceneRequest

    cfg = load_config(["quick"], ["rerender.new_views=3", "rerender.trajectory=orbit", "rerender.frames=5"])
    more = MoreViews.from_config(cfg.rerender, cfg.scene)
    assert more is not None
    req = SceneRequest.for_outputs(SceneOutputs.from_config(cfg.compose), stage="/x/scene.usda", out_dir="/x",
                                   threads=1, oracle=False, more_views=more)
    again = SceneRequest.from_dict(json.loads(json.dumps(req.to_dict())))
    assert again == req and again.more_views is not None
    assert again.more_views.plan.camera_rule.camera_elevation_deg == tuple(cfg.scene.camera_elevation_deg)
