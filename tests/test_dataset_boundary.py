"""A dataset holds only what it says it holds (issue 68): ``compose --package-assets`` copies only files that
came from the catalog's libraries, lists each with its source, and reports the bytes it wrote; no JSON a
dataset or an export writes holds an absolute path of this machine.

One real quick compose (48 px) from a demo catalog copy whose train split is two textured OBJ boxes of a
library of the test's own. Then the catalog is made hostile the way an old catalog or a library changed
after ingest is: the drawn box's MTL names a texture outside every library by its absolute path, and the
catalog's converted asset holds that file's bytes (as a conversion that read it did). Packaging must refuse
that asset (one line each, never copied) while it copies the rest; a scan of the dataset for the planted
file's bytes and pixels finds nothing. Allowing the outside folder ([ingest] extra_roots) packages it: the
rule, not chance, refused it."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import trimesh
from PIL import Image

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def _textured_box(folder: Path, name: str, rgb: tuple[int, int, int]) -> Path:
    """``folder/<name>.obj`` with its MTL and PNG texture beside it."""
    folder.mkdir(parents=True)
    box = trimesh.creation.box(extents=(0.06, 0.04, 0.03))
    uv = np.c_[box.vertices[:, 0] / 0.06 + 0.5, box.vertices[:, 1] / 0.04 + 0.5]
    image = Image.new("RGB", (8, 8), rgb)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.SimpleMaterial(image=image))
    box.export(folder / f"{name}.obj")
    return folder / f"{name}.obj"


def _cli(capsys: Any, *args: str) -> tuple[int, str, str]:
    """``mixcount ARGS`` in this process: (exit code, stdout, stderr)."""
    from mixcount.cli import main

    capsys.readouterr()
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.fixture(scope="module")
def planted(tmp_path_factory: pytest.TempPathFactory, demo_catalog_copy: Callable[[Path, int], Path]) -> dict:
    from sqlalchemy import select

    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject, Split

    tmp = tmp_path_factory.mktemp("boundary")
    root = demo_catalog_copy(tmp / "cat", 12)
    lib = root / "boxes"
    _textured_box(lib / "red", "red", (200, 30, 30))
    _textured_box(lib / "blue", "blue", (30, 40, 200))
    db = str(root / "catalog.db")
    from mixcount.cli import main

    assert main(["--db", db, "--config", "quick", "catalog", "ingest", str(lib)]) == 0
    cat = open_catalog(f"sqlite:///{db}", data_dir="")
    with cat.session() as s:  # the boxes alone in train: the scene draws them
        mine = {o.id: o for o in s.scalars(select(CatalogObject)) if str(o.model_path).startswith(str(lib))}
        assert len(mine) == 2 and all(o.status == "active" and o.textured for o in mine.values())
        for row in s.scalars(select(Split)):
            row.split = "val"
        for oid in mine:
            s.add(Split(object_id=oid, split="train", method="random"))
        s.commit()
    usd_assets = Path(cat.usd_assets_dir)
    cat.close()
    out = tmp / "out"
    assert main(["--db", db, "--config", "quick", "compose", "--n", "1", "--seed", "1", "--resolution", "48",
                 "--out", str(out)]) == 0
    (scene,) = [p for p in (out / "scenes").iterdir() if not p.name.startswith(".")]
    spec = json.loads((scene / "metadata.json").read_text())["spec"]
    counted = {c["object_id"] for c in spec["classes"]}
    target = mine[sorted(counted & set(mine))[0]]
    key = target.content_hash
    assert (out / "assets" / f"{key}.usdc").is_symlink() and (out / "assets" / f"{key}_tex").is_symlink()

    # the catalog turned hostile: its MTL names a file outside every library, its converted texture holds it
    outside = tmp / "elsewhere" / "secret.png"
    outside.parent.mkdir()
    noise = np.random.default_rng(68).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    Image.fromarray(noise).save(outside)
    model = Path(target.model_path)
    mtl = next(model.parent.glob("*.mtl"))
    mtl.write_text("\n".join(f"map_Kd {outside}" if ln.startswith("map_Kd") else ln
                             for ln in mtl.read_text().splitlines()) + "\n")
    textures = sorted((usd_assets / f"{key}_tex").glob("*.png"))
    assert textures
    for t in textures:
        shutil.copyfile(outside, t)
    for name in ("packaged", "allowed"):  # two more copies of the linked dataset, at the same depth
        shutil.copytree(out, tmp / name, symlinks=True)
    return {"root": root, "db": db, "lib": lib, "out": out, "key": key, "outside": outside, "noise": noise,
            "tmp": tmp, "usd_assets": usd_assets}


def _holding_bytes(tree: Path, data: bytes) -> list[str]:
    return [p.relative_to(tree).as_posix() for p in sorted(tree.rglob("*"))
            if p.is_file() and not p.is_symlink() and data in p.read_bytes()]


def _holding_pixels(tree: Path, pixels: np.ndarray) -> list[str]:
    found = []
    for p in sorted(tree.rglob("*.png")):
        if p.is_symlink():
            continue
        with Image.open(p) as im:
            arr = np.asarray(im.convert("RGB"))
        if arr.shape == pixels.shape and np.array_equal(arr, pixels):
            found.append(p.relative_to(tree).as_posix())
    return found


def test_package_assets_refuses_a_texture_from_outside_the_library(planted: dict, capsys: Any) -> None:
    out, key, secret = planted["out"], planted["key"], planted["outside"].read_bytes()
    assert _holding_bytes(planted["usd_assets"] / f"{key}_tex", secret)  # the catalog does hold the planted file
    code, _out, err = _cli(capsys, "--db", planted["db"], "--config", "quick", "compose", "--n", "1", "--seed", "1",
                           "--resolution", "48", "--out", str(out), "--package-assets")
    assert code == 2, err[-3000:]
    refused = [ln for ln in err.splitlines() if ln.startswith("refused ")]
    assert sorted(ln.split(":")[0] for ln in refused) == [f"refused {key}.usdc", f"refused {key}_tex"], refused
    assert all(str(planted["outside"]) in ln and "outside the library" in ln for ln in refused)
    assert "2 asset entries of" in err and "refused (listed above)" in err
    assets = out / "assets"
    assert not (assets / f"{key}.usdc").exists() and not (assets / f"{key}_tex").exists()
    assert not any(p.is_symlink() for p in assets.rglob("*"))  # the rest copied
    assert _holding_bytes(out, secret) == [] and _holding_pixels(out, planted["noise"]) == []
    listed = json.loads((out / "package.json").read_text())
    assert [r["entry"] for r in listed["refused"]] == [f"{key}.usdc", f"{key}_tex"]
    assert {f["file"] for f in listed["files"]} == {f"assets/{p.relative_to(assets).as_posix()}"
                                                   for p in assets.rglob("*") if p.is_file()}
    for f in listed["files"]:  # each with its source: a library by name and id, a path relative to it
        assert f["sources"] and all(not os.path.isabs(s["path"]) and not s["path"].startswith("..")
                                    and "#" in s["library_id"] for s in f["sources"]), f
    boxes = [s for f in listed["files"] for s in f["sources"] if s["library"] == "boxes"]
    assert boxes and all(s["path"].split("/")[0] in ("red", "blue") for s in boxes)


def test_packaged_bytes_are_those_written_and_an_allowed_root_lets_the_file_in(planted: dict, capsys: Any) -> None:
    key, secret = planted["key"], planted["outside"].read_bytes()
    copy = planted["tmp"] / "packaged"
    from mixcount.catalog.db import open_catalog

    other = planted["tmp"] / "other.db"
    open_catalog(f"sqlite:///{other}", data_dir="").close()
    links = sorted(p.name for p in (copy / "assets").iterdir() if p.is_symlink())
    code, _out, err = _cli(capsys, "--db", str(other), "package", str(copy))  # another catalog cannot vouch,
    assert code == 2 and "was composed from the catalog catalog.db#" in err, err[-2000:]  # and takes nothing out
    assert sorted(p.name for p in (copy / "assets").iterdir() if p.is_symlink()) == links and links
    code, stdout, err = _cli(capsys, "--db", planted["db"], "package", str(copy), "--json")
    assert code == 2, err[-2000:]  # the planted asset refused here too
    report = json.loads(stdout)
    assert report["refused_entries"] == [f"{key}.usdc", f"{key}_tex"] and report["checked"]
    listed = json.loads((copy / "package.json").read_text())
    on_disk = {p: p.stat().st_size for p in (copy / "assets").rglob("*") if p.is_file()}
    assert listed["bytes"] == sum(on_disk.values()) == sum(f["bytes"] for f in listed["files"])
    written = [f for f in listed["files"] if f["written"]]  # bpy's HDRI was copied in by compose already
    assert report["bytes"] == sum(on_disk[copy / f["file"]] for f in written) > 0
    assert all(f["entry"] not in report["refused_entries"] for f in listed["files"])
    assert _holding_bytes(copy, secret) == []

    allowed = planted["tmp"] / "allowed"
    code, stdout, err = _cli(capsys, "--db", planted["db"], "--set",
                             f"ingest.extra_roots=[{json.dumps(str(planted['outside'].parent))}]",
                             "package", str(allowed), "--json")
    assert code == 0, err[-2000:]
    assert json.loads(stdout)["refused"] == 0
    assert _holding_bytes(allowed, secret)  # the folder allowed now: its file is packaged, and listed
    listed = json.loads((allowed / "package.json").read_text())
    tex = [f for f in listed["files"] if f["entry"] == f"{key}_tex"]
    assert tex and any(s["library"] == "elsewhere" and s["path"] == "secret.png" for s in tex[0]["sources"])


def test_no_json_of_the_dataset_or_an_export_holds_a_path_of_this_machine(planted: dict) -> None:
    from mixcount.export import export_dataset

    out = planted["tmp"] / "packaged"
    exported = planted["tmp"] / "fsc147"
    export_dataset(out, "fsc147", exported)
    manifest = json.loads((exported / "mixcount_export.json").read_text())
    assert manifest["dataset"]["path"] == "../packaged" and manifest["dataset"]["name"] == "packaged"
    needles = {str(Path(p).resolve()) for p in (out, exported, planted["root"], planted["lib"],
                                                planted["outside"].parent, planted["tmp"])}
    home = os.path.expanduser("~")
    if home not in ("", "/"):
        needles.add(home.rstrip("/") + "/")
    leaks = []
    for tree in (out, exported):
        for p in sorted(tree.rglob("*")):
            if p.suffix in (".json", ".jsonl") and not p.relative_to(tree).as_posix().startswith("logs/"):
                text = p.read_text(encoding="utf-8")
                leaks += [f"{p.relative_to(tree)}: {n}" for n in needles if n in text]
    assert leaks == [], leaks[:20]
    assert any((out / "scenes").rglob("metadata.json")) and (out / "dataset.json").is_file()
