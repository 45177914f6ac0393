"""Datasets that travel (issue 26), on one real composed dataset with two splits (demo library -> real
ingest -> the bottles in train, the rest in val -> real compose of 2 train and 2 val scenes at 96 px):

- the paper's cross-scene external exemplars: in the merged COCO categories and the fsc147 and countgd
  exports, always from other scenes of the same split;
- a dataset moved to another folder with the catalog gone (``mixcount package`` finding the assets
  through ``MIXCOUNT_ASSETS``): every stage opens in a fresh usd-core process with every reference
  resolved and no UsdValidation error, no file holds a path of this machine, merge / verify / export
  work, and a scene re-renders from the moved stage with the same masks;
- the README's Python API example, run as written.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.cli import main

pytestmark = [pytest.mark.blender, pytest.mark.slow]
PROJECT_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def two_splits(composed_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(catalog root, dataset) composed from a copy of composed_dataset's catalog: the bottles in train,
    every other object in val."""
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject, Split

    root = tmp_path_factory.mktemp("portable")
    shutil.copyfile(composed_dataset.parent / "catalog.db", root / "catalog.db")
    cat = open_catalog(f"sqlite:///{root / 'catalog.db'}", data_dir="")
    with cat.session() as session:  # train: the three bottles only, so its two scenes share an object
        category = {o.id: o.category for o in session.query(CatalogObject)}
        for row in session.query(Split):
            row.split = "train" if category[row.object_id] == "bottle" else "val"
        session.commit()
    cat.close()
    out = root / "out"
    for split, seed in (("train", 5), ("val", 9)):
        rc = main(["--db", str(root / "catalog.db"), "--config", "quick", "--set", "scene.n_objects=[16,24]",
                   "compose", "--n", "2", "--split", split, "--seed", str(seed), "--resolution", "96", "--out", str(out)])
        assert rc == 0
    return root, out


def _split_scenes(out: Path) -> dict[str, set[str]]:
    return {p.stem[len("instances_"):]: {img["scene_id"] for img in json.loads(p.read_text())["images"]}
            for p in sorted((out / "annotations").glob("instances_*.json"))}


def test_cross_scene_exemplars_come_from_other_scenes_of_the_same_split(two_splits: tuple[Path, Path],
                                                                     tmp_path: Path) -> None:
    from mixcount.export import export_dataset

    _root, out = two_splits
    scenes = _split_scenes(out)
    assert sorted(scenes) == ["train", "val"] and all(len(v) == 2 for v in scenes.values())
    usable = 0
    for split, own in scenes.items():
        coco = json.loads((out / "annotations" / f"instances_{split}.json").read_text())
        anns = {a["id"]: a for a in coco["annotations"]}
        for cat in coco["categories"]:
            entries = cat["cross_scene_exemplars"]
            assert [e["exemplar_score"] for e in entries] == sorted((e["exemplar_score"] for e in entries), reverse=True)
            for e in entries:
                assert e["scene_id"] in own  # never another split's scene
                a = anns[e["annotation_id"]]  # merged ids of this split's file
                assert a["scene_id"] == e["scene_id"] and a["bbox"] == e["bbox"]
                assert a["exemplar_score"] == e["exemplar_score"] and not a["is_distractor"]
                with Image.open(out / e["crop"]) as im:  # the crop of that box (10 % margin)
                    assert im.width >= int(e["bbox"][2]) and im.height >= int(e["bbox"][3])
        for img in coco["images"]:
            for ex in img["exemplars"]:
                cat = next(c for c in coco["categories"] if c["id"] == ex["category_id"])
                usable += sum(1 for e in cat["cross_scene_exemplars"] if e["scene_id"] != img["scene_id"])
    assert usable > 0  # an object shown in both scenes of a split

    fsc = tmp_path / "fsc147"
    export_dataset(out, "fsc147", fsc)
    ann = json.loads((fsc / "annotation_FSC147_384.json").read_text())
    listed = 0
    for name, rec in ann.items():
        split, own = rec["mixcount"]["split"], rec["mixcount"]["scene_id"]
        assert len(rec["cross_scene_exemplars"]) <= 3
        for e in rec["cross_scene_exemplars"]:
            assert e["scene_id"] != own and e["scene_id"] in scenes[split], name
            assert (fsc / e["file"]).is_file()
            listed += 1
    assert listed > 0

    cgd = tmp_path / "countgd"
    export_dataset(out, "countgd", cgd)
    listed = 0
    for split in scenes:
        for line in (cgd / f"{split}_odvg.jsonl").read_text().splitlines():
            rec = json.loads(line)
            for e in rec["external_exemplars"]:
                assert e["scene_id"] != rec["mixcount"]["scene_id"] and e["scene_id"] in scenes[split]
                with Image.open(cgd / "images" / e["filename"]) as im:  # an image of this export
                    x1, y1, x2, y2 = e["exemplar"]
                    assert 0 <= x1 < x2 <= im.width and 0 <= y1 < y2 <= im.height
                listed += 1
    assert listed > 0


def _machine_paths(*extra: Path) -> list[str]:
    """Absolute paths of this machine that a dataset must not hold: where it was made, the project, the
    Python environment (bpy's bundled HDRIs live there), the temporary root."""
    import tempfile

    roots = {str(Path(p).resolve()) for p in (*extra, PROJECT_ROOT, sys.prefix)}
    return sorted(roots | {tempfile.gettempdir().rstrip("/") + "/"})


def _files_holding(tree: Path, needles: list[str]) -> list[str]:
    """Files (and link targets) under ``tree`` holding any of ``needles``; ``logs/`` (the workers' logs of
    the machine that composed, not part of a published dataset) left out."""
    found = []
    pattern = re.compile("|".join(re.escape(n) for n in needles).encode())
    for p in sorted(tree.rglob("*")):
        rel = p.relative_to(tree).as_posix()
        if rel.startswith("logs/") or rel == "logs":
            continue
        if p.is_symlink():
            if pattern.search(os.readlink(p).encode()) or os.path.isabs(os.readlink(p)):
                found.append(f"{rel} -> {os.readlink(p)}")
        elif p.is_file() and pattern.search(p.read_bytes()):
            found.append(rel)
    return found


def test_moved_dataset_opens_merges_exports_and_rerenders_without_the_catalog(two_splits: tuple[Path, Path],
                                                                             tmp_path: Path) -> None:
    from test_usd_stage import run_child

    from mixcount.config import load_config
    from mixcount.export import export_dataset
    from mixcount.worker.client import BlenderWorker
    from mixcount.worker.contract import SceneRequest

    root, out = two_splits
    needles = _machine_paths(root, out)
    assert _files_holding(out, needles) == []  # composed: stages, metadata, merged files, links all relative
    assert (out / "assets").is_dir() and any(p.is_symlink() for p in (out / "assets").iterdir())

    moved = tmp_path / "elsewhere" / "dataset"
    shutil.copytree(out, moved, symlinks=True)
    catalog_assets = root / "usd_assets"
    hidden = tmp_path / "hidden_assets"
    os.rename(catalog_assets, hidden)  # the catalog's converted assets are gone from where the links point
    try:
        env = {**os.environ, "MIXCOUNT_ASSETS": str(hidden)}
        proc = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(root / "catalog.db"), "package", str(moved),
                               "--json"], capture_output=True, text=True, env=env, timeout=300)  # the catalog vouches
        assert proc.returncode == 0, proc.stderr[-2000:]
        report = json.loads(proc.stdout)
        assert report["copied"] > 0 and report["found_by_search"] > 0
        assert not any(p.is_symlink() for p in (moved / "assets").rglob("*"))
        stages = sorted(moved.glob("scenes/*/*.usda"))
        assert len(stages) == 8
        for stage in stages:  # a fresh usd-core process, nothing of mixcount imported
            info = run_child(stage)
            assert info["errors"] == [] and info["unresolved"] == [], (stage, info["errors"], info["unresolved"])
        leaks = _files_holding(moved, [*needles, str(moved.parent)])
        assert leaks == [], leaks[:20]

        for cmd in (["merge", str(moved)], ["verify", str(moved)]):
            proc = subprocess.run([sys.executable, "-m", "mixcount", *cmd], capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, (cmd, proc.stderr[-2000:])
        manifest = export_dataset(moved, "fsc147", tmp_path / "fsc147")
        assert manifest["figures"]["samples"] > 0

        scene = sorted((moved / "scenes").iterdir())[0]
        cfg = load_config(["quick"], [])
        with BlenderWorker(name="moved", log_dir=tmp_path) as worker:
            req = SceneRequest(stage=str(scene / "scene.usda"), out_dir=str(tmp_path / "again"), threads=2, oracle=False,
                               passes=("instance",), depth_format=cfg.compose.depth_format,
                               normal_format=cfg.compose.normal_format, mesh_cache="off", settled_poses_file="",
                               more_views=None)
            (tmp_path / "again").mkdir()
            result = worker.run_scene_job(req, timeout=600)
        assert result.status == "ok"
        ids = np.load(tmp_path / "again" / "ids.npy").astype(np.uint16)
        assert np.array_equal(ids, np.asarray(Image.open(scene / "instance.png")))  # the same masks
    finally:
        os.rename(hidden, catalog_assets)


def _readme_example() -> str:
    text = (PROJECT_ROOT / "README.md").read_text()
    section = text.split("## Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)  # type: ignore[union-attr]


def test_readme_python_api_example_runs_as_written(two_splits: tuple[Path, Path], tmp_path: Path) -> None:
    root, out = two_splits
    (tmp_path / "catalog").mkdir()
    shutil.copyfile(root / "catalog.db", tmp_path / "catalog" / "catalog.db")
    code = _readme_example()
    assert code.count("\n") <= 12  # a ten-line example
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines and lines[0].startswith("scene_")
    ds = json.loads((tmp_path / "out" / "api" / "dataset.json").read_text())
    assert ds["counts"]["scenes"] == 1
    for line in lines[1:]:
        assert re.fullmatch(r"  \d+ x .+: \d+ exemplar crops", line), line
    api_out = tmp_path / "out" / "api"
    assert any(p.is_symlink() for p in (api_out / "assets").iterdir())  # links into the catalog so far

    # the same compose again with --package-assets: the finished scene is kept, the assets are copied in
    rc = main(["--db", str(tmp_path / "catalog" / "catalog.db"), "--config", "quick", "compose", "--n", "1",
               "--split", "train", "--resolution", "96", "--out", str(api_out), "--package-assets"])
    assert rc == 0
    assert not any(p.is_symlink() for p in (api_out / "assets").rglob("*"))
    assert json.loads((api_out / "dataset.json").read_text())["counts"]["scenes"] == 1

    # reading needs neither bpy nor pxr; every array matches the merged COCO
    check = f"""
import json, sys
import mixcount
ds = mixcount.load_dataset({str(out)!r})
coco = {{s: json.load(open({str(out)!r} + f"/annotations/instances_{{s}}.json")) for s in ds.splits}}
n = 0
for s in ds.samples():
    anns = [a for a in coco[s.split]["annotations"] if a["image_id"] == s.image_id]
    m = s.masks()
    assert m.shape == (len(anns), s.height, s.width) and s.boxes.tolist() == [a["bbox"] for a in anns]
    assert [int(v) for v in m.sum(axis=(1, 2))] == [a["area"] for a in anns]
    assert all(m[k, int(y), int(x)] for k, (x, y) in enumerate(s.points))
    for cid, count in s.counts.items():
        assert count == sum(1 for a in anns if a["category_id"] == cid)
        kinds = [e.kind for e in s.exemplars[cid]]
        assert kinds.count("internal") >= 1 and all(e.image().size[0] > 0 for e in s.exemplars[cid])
        assert all(e.scene_id != s.scene_id for e in s.exemplars[cid] if e.kind == "cross_scene")
        assert set(s.captions[cid]) == {{"short", "concise", "detailed"}}
    assert s.depth().shape == (s.height, s.width)
    n += 1
assert n == len(ds) == 4
print("bpy" in sys.modules, "pxr" in sys.modules)
"""
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["False", "False"]
