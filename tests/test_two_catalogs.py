"""Two catalogs in one folder (issue 35, item 1): each one's canonical renders, contact sheets, external
exemplars and scene assets are its own objects', although both number their rows 1, 2, ...

Real everything: two demo libraries ingested into ``cats/a.db`` and ``cats/b.db`` through the CLI, real
bpy canonical renders (32 px, 1 sample), real sheets, a real one-scene compose from each catalog."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pxr import Sdf
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, Split
from mixcount.cli import main
from mixcount.curation.renders import canonical_render_path

pytestmark = [pytest.mark.blender, pytest.mark.slow]

SMALL = ["--config", "quick", "--set", "canonical_render.resolution=32", "--set", "canonical_render.samples=1"]


def cli(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def make_catalog(capsys, root: Path, db: Path, seed: int) -> None:
    """demo-library -> catalog ingest (CLI), every active object in train."""
    lib = root / f"lib{seed}"
    assert cli(capsys, "demo-library", str(lib), "--seed", str(seed), "--n", "8")[0] == 0
    code, _, err = cli(capsys, "--db", str(db), *SMALL, "catalog", "ingest", str(lib), "--workers", "1")
    assert code == 0, err
    cat = open_catalog(str(db), data_dir="")
    with cat.session() as s:
        for obj in s.scalars(select(CatalogObject).where(CatalogObject.status == "active")):
            s.add(Split(object_id=obj.id, split="train", method="random"))
        s.commit()
    cat.close()


def renders_of(db: Path) -> dict[int, Path]:
    cat = open_catalog(str(db), data_dir="")
    try:
        with cat.session() as s:
            ids = [o.id for o in s.scalars(select(CatalogObject).where(CatalogObject.status == "active"))]
            paths = {i: canonical_render_path(s, i) for i in ids}
    finally:
        cat.close()
    assert all(p is not None for p in paths.values())
    return {i: p for i, p in paths.items() if p is not None}


def test_two_catalogs_in_one_folder_keep_their_own_files(tmp_path, capsys):
    cats = tmp_path / "cats"
    a, b = cats / "a.db", cats / "b.db"
    make_catalog(capsys, tmp_path, a, seed=1)
    make_catalog(capsys, tmp_path, b, seed=2)

    code, _, err = cli(capsys, "--db", str(a), *SMALL, "catalog", "render")
    assert code == 0, err
    a_bytes = {i: p.read_bytes() for i, p in renders_of(a).items()}
    code, _, err = cli(capsys, "--db", str(b), *SMALL, "catalog", "render")
    assert code == 0, err
    ra, rb = renders_of(a), renders_of(b)
    # rendering b did not touch a's pictures
    assert {i: p.read_bytes() for i, p in ra.items()} == a_bytes, "catalog b's renders overwrote a's"
    shared = sorted(set(ra) & set(rb))
    assert len(shared) >= 8  # both catalogs number their rows 1, 2, ...
    for i in shared:
        assert ra[i].parent == cats / "renders" / "a" and rb[i].parent == cats / "renders" / "b"
        assert ra[i].name == rb[i].name == f"obj_{i:06d}.png"
    # the two libraries hold other objects under the same ids: at least some pictures differ
    assert sum(ra[i].read_bytes() != rb[i].read_bytes() for i in shared) >= len(shared) // 2

    # a's renders are still up to date and still its own
    code, out, err = cli(capsys, "--db", str(a), *SMALL, "catalog", "render")
    assert code == 0 and f"{len(ra)} objects, 0 rendered, {len(ra)} up to date" in out + err
    assert {i: p.read_bytes() for i, p in renders_of(a).items()} == a_bytes

    # sheets: each catalog's page is made of its own renders (a's page differs from b's)
    for db, name in ((a, "sheets_a"), (b, "sheets_b")):
        assert cli(capsys, "--db", str(db), *SMALL, "catalog", "sheet", "--out", str(tmp_path / name))[0] == 0
    sheet_a = np.asarray(Image.open(tmp_path / "sheets_a" / "sheet_001.png").convert("RGB"))
    sheet_b = np.asarray(Image.open(tmp_path / "sheets_b" / "sheet_001.png").convert("RGB"))
    assert sheet_a.shape == sheet_b.shape and np.abs(sheet_a.astype(int) - sheet_b.astype(int)).mean() > 1.0

    # compose one scene from each: external exemplars are that catalog's renders, assets its own folder
    for db, key in ((a, "a"), (b, "b")):
        out = tmp_path / f"out_{key}"
        code, _, err = cli(capsys, "--db", str(db), "--config", "quick", "--set", "scene.n_objects=[6,10]",
                           "compose", "--n", "1", "--split", "train", "--resolution", "32", "--samples", "1",
                           "--out", str(out))
        assert code == 0, err
        own = renders_of(db)
        exemplars = sorted((out / "exemplars" / "external").glob("obj_*.png"))
        assert exemplars
        for ex in exemplars:
            oid = int(ex.stem.split("_")[1])
            assert ex.read_bytes() == own[oid].read_bytes(), f"{ex.name} is not catalog {key}'s object {oid}"
        # the scene's assets: links into this catalog's own asset folder, converted from its own library
        linked = sorted((out / "assets").glob("*.usdc"))
        assert linked
        lib = tmp_path / f"lib{1 if key == 'a' else 2}"
        for link in linked:
            assert link.resolve().parent == (cats / "usd_assets" / key).resolve()
            source = Path(Sdf.Layer.FindOrOpen(str(link.resolve())).customLayerData["mixcount"]["source"])
            assert source.resolve().is_relative_to(lib.resolve()), f"{link.name} comes from {source}"
        settings = json.loads((out / "settings.json").read_text())
        assert settings["variants"][0]["settings"]["catalog"].startswith(f"{key}.db#")
