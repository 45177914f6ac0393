"""bpy's bundled HDRIs as the default light: found in bpy's install without importing bpy, their
licence read from the ``license.txt`` beside them, a real Cycles render lit by one, and ATTRIBUTION
naming it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mixcount.errors import ConfigError
from mixcount.scene.bundled_environments import (
    BUNDLED_SOURCE,
    bpy_package_dir,
    bundled_environments,
    bundled_hdri_dir,
    bundled_license,
    is_bundled_path,
    parse_license,
)
from tests.conftest import PROJECT_ROOT

NAMES = ["city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset"]


def test_bundled_hdris_are_found_in_bpys_install_without_importing_bpy() -> None:
    code = ("import sys; from mixcount.scene.bundled_environments import bundled_environments as b; "
            "envs = b(); print(len(envs), envs[0].path); assert 'bpy' not in sys.modules, 'bpy imported'")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stderr
    n, first = done.stdout.split()
    assert n == "8" and Path(first).is_file()
    envs = bundled_environments()
    assert [e.name for e in envs] == NAMES
    folder = bundled_hdri_dir()
    assert folder.is_relative_to(bpy_package_dir()) and folder.parts[-3:] == ("datafiles", "studiolights", "world")
    for e in envs:
        assert Path(e.path).parent == folder and e.environment_id is None and e.source == BUNDLED_SOURCE
        assert Path(e.path).read_bytes()[:4] == b"\x76\x2f\x31\x01"  # OpenEXR magic
        assert is_bundled_path(e.path)
        assert len(e.content_hash) == 64
    assert not str(folder).startswith(str(PROJECT_ROOT / "mixcount"))  # used where bpy installed them
    assert not is_bundled_path("/data/hdri/city.exr")


def test_missing_bundle_is_a_clear_config_error(tmp_path: Path) -> None:
    (tmp_path / "5.0" / "datafiles").mkdir(parents=True)
    with pytest.raises(ConfigError, match="no bundled HDRIs under .*default_environment = \"sky\""):
        bundled_hdri_dir(tmp_path)
    world = tmp_path / "5.1" / "datafiles" / "studiolights" / "world"
    world.mkdir(parents=True)
    assert bundled_hdri_dir(tmp_path) == world  # the newest version folder holding them
    with pytest.raises(ConfigError, match="no .exr HDRIs"):
        bundled_environments(tmp_path)


def test_compose_without_the_bundle_stops_before_any_scene(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bpy without its studio-light HDRIs (here: bpy's folder pointed at an empty one) is one clear
    error before any worker starts or scene folder is written; the sky config composes on."""
    from test_scene_distributions import rich_pool

    from mixcount.config import load_config
    from mixcount.run.compose import compose_scenes
    from mixcount.scene import bundled_environments as B

    monkeypatch.setattr(B, "bpy_package_dir", lambda: tmp_path / "bpy")
    (tmp_path / "bpy").mkdir()
    with pytest.raises(ConfigError, match="no bundled HDRIs under .*bpy"):
        compose_scenes(pool=rich_pool(), config=load_config(), out_dir=tmp_path / "out", assets_dir=tmp_path / "a", n=1,
                       progress=False)
    assert list((tmp_path / "out" / "scenes").iterdir()) == [] and not (tmp_path / "out" / "logs").exists()
    from mixcount.scene.environment_sampling import environments_to_draw

    assert environments_to_draw(load_config([], ["scene.default_environment=sky"]).scene, ()) == ()


def test_license_txt_names_every_original() -> None:
    text = (bundled_hdri_dir() / "license.txt").read_text()
    info = parse_license(text)
    assert info["license"] == "CC0" and info["author"] == "Greg Zaal"
    assert info["source"] == "Poly Haven" and info["source_url"] == "https://polyhaven.com"
    assert sorted(info["originals"]) == NAMES
    assert info["originals"]["city"] == {"url": "https://polyhaven.com/a/portland_landing_pad", "uncertain": False}
    assert info["originals"]["night"]["uncertain"] is True  # "Probably https://..."
    for e in bundled_environments():
        lic = bundled_license(e.path)
        assert lic is not None and lic["name"] == e.name and lic["license"] == "CC0"
        assert lic["original_url"].startswith("https://polyhaven.com/a/")
    # a dataset made elsewhere (its bpy path gone here) still gets the licence from the local bpy
    moved = bundled_license("/elsewhere/bpy/5.0/datafiles/studiolights/world/forest.exr")
    assert moved is not None and moved["original_url"] == "https://polyhaven.com/a/ninomaru_teien"


def _compose(out: Path, assets: Path, pool: list, strength: float, *extra: str) -> Path:
    from mixcount.config import load_config
    from mixcount.run.compose import compose_scenes

    cfg = load_config([PROJECT_ROOT / "configs" / "quick.toml"],
                      ["compose.render_threads=2", "compose.resolution=64", "compose.samples=2", "compose.seed=3",
                       "scene.n_objects=[6,8]", f"scene.environment_strength=[{strength},{strength}]", *extra])
    summary = compose_scenes(pool=pool, config=cfg, out_dir=out, assets_dir=assets, n=1, progress=False)
    assert summary.written == 1 and summary.failed == 0
    return next(d for d in (out / "scenes").iterdir() if d.is_dir() and not d.name.startswith("."))


@pytest.fixture(scope="module")
def demo6(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The seed-0 demo library of 6 objects, generated once for the module's two renders (read only)."""
    from mixcount.demo.library import generate_demo_library

    root = tmp_path_factory.mktemp("demo6") / "demo"
    generate_demo_library(root, seed=0, n_objects=6)
    return root


@pytest.mark.blender
@pytest.mark.slow
def test_real_render_lit_by_a_bundled_hdri_and_attribution_names_it(tmp_path: Path, demo6: Path) -> None:
    from PIL import Image

    from mixcount.dataset.attribution import write_attribution
    from mixcount.demo.demo_pools import pool_from_demo_library

    pool = pool_from_demo_library(demo6)
    dim = _compose(tmp_path / "dim", tmp_path / "assets", pool, 0.3)
    bright = _compose(tmp_path / "bright", tmp_path / "assets", pool, 2.0)
    meta = json.loads((dim / "metadata.json").read_text())
    env = meta["spec"]["environment"]
    # recorded portably (docs/usd.md): "bpy:<path in the bpy package>", resolved on any machine with bpy
    from mixcount.usd.portable import resolve_bpy_path

    assert env["kind"] == "hdri" and env["path"].startswith("bpy:") and is_bundled_path(env["path"])
    assert resolve_bpy_path(env["path"]).is_file()
    # the worker built the world from the stage's dome light: that texture (the dataset's entry, a copy or
    # hard link of bpy's map), strength and turn
    dome = meta["lights"]["dome"]
    assert dome == {"kind": "hdri", "path": f"assets/environments/{Path(env['path']).name}",
                    "strength": pytest.approx(0.3), "rotation_deg": pytest.approx(env["rotation_deg"])}
    entry = tmp_path / "dim" / dome["path"]
    assert not entry.is_symlink() and entry.read_bytes() == resolve_bpy_path(env["path"]).read_bytes()
    assert "sun" not in meta["lights"]  # the sun lamp belongs to the procedural sky
    assert json.loads((bright / "metadata.json").read_text())["spec"]["environment"]["path"] == env["path"]
    a = np.asarray(Image.open(dim / "rgb.png").convert("RGB"), dtype=np.float64)
    b = np.asarray(Image.open(bright / "rgb.png").convert("RGB"), dtype=np.float64)
    assert a.std() > 3.0  # a lit scene, not a flat or black image
    assert b.mean() > 1.3 * a.mean()  # the HDRI is what lights it: its strength brightens the same scene

    doc = write_attribution(tmp_path / "dim", tmp_path / "export")
    assert len(doc["environments"]) == 1
    e = doc["environments"][0]
    name = Path(env["path"]).stem
    assert e["path"] == env["path"] and e["scenes"] == 1 and e["source"] == BUNDLED_SOURCE
    assert (e["license"], e["author"], e["provider"]) == ("CC0", "Greg Zaal", "Poly Haven")
    assert e["original_url"] == parse_license(e["license_text"])["originals"][name]["url"]
    md = (tmp_path / "export" / "ATTRIBUTION.md").read_text()
    assert "CC0, by Greg Zaal (Poly Haven https://polyhaven.com)" in md and e["original_url"] in md
    assert json.loads((tmp_path / "export" / "ATTRIBUTION.json").read_text())["environments"][0]["license"] == "CC0"


@pytest.mark.blender
@pytest.mark.slow
def test_sky_config_still_renders_the_procedural_sky(tmp_path: Path, demo6: Path) -> None:
    from PIL import Image

    from mixcount.dataset.attribution import collect_attribution
    from mixcount.demo.demo_pools import pool_from_demo_library

    scene = _compose(tmp_path / "sky", tmp_path / "assets", pool_from_demo_library(demo6), 1.0,
                     "scene.default_environment=sky")
    meta = json.loads((scene / "metadata.json").read_text())
    env = meta["spec"]["environment"]
    assert env["kind"] == "sky" and env["path"] is None
    assert meta["lights"]["dome"]["kind"] == "uniform"  # the sky tint, no texture
    assert meta["lights"]["sun"]["strength"] == pytest.approx(env["sun_strength"])
    assert np.asarray(Image.open(scene / "rgb.png").convert("L"), dtype=np.float64).std() > 3.0
    assert collect_attribution(tmp_path / "sky")["environments"] == []  # nothing to attribute
