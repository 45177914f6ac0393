"""``mixcount package`` and the portable path rules on small real USD layers (pxr only, no bpy): links
become copies, copied layers lose this machine's paths (in the bytes, not only in what USD shows), a broken
link is found through MIXCOUNT_ASSETS, and an asset found nowhere is one clear error that loses nothing.
The whole path on a real composed dataset is tests/test_portable_dataset.py."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mixcount.dataset.package import PackageError, package_assets
from mixcount.usd.portable import PathRoots, link_into_dataset, portable_paths, resolve_bpy_path, stage_reference


def _asset(catalog: Path, key: str) -> Path:
    """A converted-asset-like layer: a mesh, a texture folder, customLayerData naming absolute sources."""
    from pxr import Sdf, Usd, UsdGeom

    catalog.mkdir(parents=True, exist_ok=True)
    path = catalog / f"{key}.usdc"
    stage = Usd.Stage.CreateNew(str(path))
    root = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(root.GetPrim())
    UsdGeom.Mesh.Define(stage, "/Asset/mesh").CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    stage.GetRootLayer().customLayerData = {"mixcount": {"source": str(catalog.parent / "lib" / "model.glb"),
                                                         "proxy": str(catalog.parent / "proxies" / "p.ply")}}
    stage.GetRootLayer().Save()
    (catalog / f"{key}_tex").mkdir(exist_ok=True)
    (catalog / f"{key}_tex" / "base.png").write_bytes(b"png bytes")
    assert Sdf.Layer.FindOrOpen(str(path)) is not None
    return path


def _dataset(out: Path, catalog: Path, keys: list[str]) -> Path:
    """OUT/scenes/s/scene.usda referencing each asset through OUT/assets (links made as compose makes them)."""
    from pxr import Usd, UsdGeom

    scene = out / "scenes" / "scene_000001"
    scene.mkdir(parents=True)
    stage = Usd.Stage.CreateNew(str(scene / "scene.usda"))
    for k, key in enumerate(keys):
        src = catalog / f"{key}.usdc"
        link_into_dataset(out, src, src.name)
        link_into_dataset(out, catalog / f"{key}_tex", f"{key}_tex")
        prim = UsdGeom.Xform.Define(stage, f"/World/obj_{k}").GetPrim()
        prim.GetReferences().AddReference(stage_reference(out, scene, src.name))
    stage.GetRootLayer().Save()
    return scene / "scene.usda"


def _unresolved(stage_path: Path) -> list[str]:
    from pxr import Sdf, UsdUtils

    _layers, _assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(stage_path)))
    return [str(u) for u in unresolved]


def test_package_replaces_links_by_clean_copies_and_the_dataset_opens_without_the_catalog(tmp_path: Path) -> None:
    catalog = tmp_path / "catalog" / "usd_assets"
    _asset(catalog, "aaaa")
    _asset(catalog, "bbbb")
    out = tmp_path / "out"
    stage = _dataset(out, catalog, ["aaaa", "bbbb"])
    link = out / "assets" / "aaaa.usdc"
    assert link.is_symlink() and not os.path.isabs(os.readlink(link))  # a relative link, no machine path
    assert "../../assets/aaaa.usdc" in stage.read_text() and str(tmp_path) not in stage.read_text()
    assert _unresolved(stage) == []

    report = package_assets(out)
    assert report.to_dict()["copied"] == 4 and report.to_dict()["layers_rewritten"] == 2
    assert not any(p.is_symlink() for p in (out / "assets").rglob("*"))
    assert (out / "assets" / "aaaa_tex" / "base.png").read_bytes() == b"png bytes"
    for key in ("aaaa", "bbbb"):
        data = (out / "assets" / f"{key}.usdc").read_bytes()
        assert str(tmp_path).encode() not in data  # gone from the file, not only from the layer's API
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(out / "assets" / "aaaa.usdc"))
    assert layer.customLayerData["mixcount"] == {"source": "source:model.glb", "proxy": "source:p.ply"}

    moved = tmp_path / "elsewhere" / "out"
    moved.parent.mkdir()
    os.rename(out, moved)
    os.rename(tmp_path / "catalog", tmp_path / "gone")
    assert _unresolved(moved / "scenes" / "scene_000001" / "scene.usda") == []
    again = package_assets(moved)  # a second run keeps the copies
    assert again.to_dict()["copied"] == 0 and again.to_dict()["kept"] == 4


def test_broken_links_are_found_through_mixcount_assets_else_one_error_naming_them(tmp_path: Path,
                                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from mixcount.cli import main

    catalog = tmp_path / "catalog" / "usd_assets"
    _asset(catalog, "cccc")
    _asset(catalog, "dddd")
    out = tmp_path / "out"
    _dataset(out, catalog, ["cccc", "dddd"])
    moved = tmp_path / "copy"
    import shutil

    shutil.copytree(out, moved, symlinks=True)
    shutil.copytree(catalog, tmp_path / "backup")
    shutil.rmtree(tmp_path / "catalog")
    (tmp_path / "backup" / "dddd.usdc").unlink()  # one asset is nowhere

    monkeypatch.setenv("MIXCOUNT_ASSETS", str(tmp_path / "backup"))
    with pytest.raises(PackageError, match=r"1 asset\(s\) .* found nowhere .*dddd\.usdc"):
        package_assets(moved)
    assert (moved / "assets" / "cccc.usdc").is_file() and not (moved / "assets" / "cccc.usdc").is_symlink()
    assert (moved / "assets" / "dddd.usdc").is_symlink()  # left as it was: nothing lost
    assert main(["package", str(moved)]) == 2  # the CLI: one line, exit 2

    shutil.copyfile(tmp_path / "backup" / "cccc.usdc", tmp_path / "backup" / "dddd.usdc")  # found again
    report = package_assets(moved)
    assert "dddd.usdc" in report.searched and report.kept == ["cccc.usdc", "cccc_tex", "dddd_tex"]
    assert main(["package", str(tmp_path / "nothing")]) == 2  # no scenes/ folder


def test_portable_paths_rules(tmp_path: Path) -> None:
    out, assets = tmp_path / "out", tmp_path / "cat" / "usd_assets"
    roots = PathRoots(out, (assets,), bpy=tmp_path / "venv" / "bpy")
    record = {"file": str(out / "scenes" / "s" / "rgb.png"), "asset": str(assets / "h.usdc"),
              "env": str(tmp_path / "venv" / "bpy" / "5.0" / "datafiles" / "studiolights" / "world" / "city.exr"),
              "model": str(tmp_path / "lib" / "mug.glb"), "prim": "/World/Objects/obj_0001",
              "text": "a mug / cup", str(assets / "h.usdc"): "hit", "n": 3, "list": [str(out / "x.json")]}
    assert portable_paths(record, roots) == {
        "file": "scenes/s/rgb.png", "asset": "assets/h.usdc", "env": "bpy:5.0/datafiles/studiolights/world/city.exr",
        "model": "source:mug.glb", "prim": "/World/Objects/obj_0001", "text": "a mug / cup", "assets/h.usdc": "hit",
        "n": 3, "list": ["x.json"]}
    with pytest.raises(ValueError):
        resolve_bpy_path("assets/h.usdc")
