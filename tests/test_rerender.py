"""``mixcount render``: finished scenes rendered again from settled.usda, no physics (issue 38).

Real bpy re-renders of the session's composed dataset (``composed_dataset``: 2 scenes at 96 px, read only;
every output goes to tmp_path): at the scenes' own cameras and settings the instance / class maps and
coco.json are identical to the originals; new views (paper camera rule, orbit) under both annotation
rules pass the one-render-per-object reference check and keep one instance id per object; ``--device gpu``
on a machine without one stops with one line, exit 2, nothing written. The camera rule itself is tested
without bpy."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mixcount.cli import main


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()}


def _render(src: Path, out: Path, *args: str) -> dict:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["--config", "quick", "render", str(src), "--out", str(out), "--json", *args])
    assert rc == 0
    return json.loads(buf.getvalue().strip().splitlines()[-1])


def _scenes(root: Path) -> list[Path]:
    return sorted((root / "scenes").glob("scene_*"))


@pytest.mark.blender
@pytest.mark.slow
def test_own_cameras_and_settings_give_identical_maps_and_coco(composed_dataset: Path, tmp_path: Path) -> None:
    before = _snapshot(composed_dataset)
    out = tmp_path / "again"
    summary = _render(composed_dataset, out)
    assert [s["status"] for s in summary["scenes"]] == ["written"] * len(_scenes(composed_dataset))
    assert _snapshot(composed_dataset) == before  # the source is only read
    n_maps = 0
    for d in _scenes(composed_dataset):
        new = out / "scenes" / d.name
        for p in sorted(d.glob("instance*.png")) + sorted(d.glob("class*.png")):
            assert np.array_equal(np.array(Image.open(p)), np.array(Image.open(new / p.name))), (d.name, p.name)
            n_maps += 1
        assert json.loads((d / "coco.json").read_text()) == json.loads((new / "coco.json").read_text())
        meta, again = (json.loads((x / "metadata.json").read_text()) for x in (d, new))
        assert again["timings"]["worker.import"] > 0 and "worker.physics" not in again["timings"]  # no physics
        for key in ("counts", "ground_truth", "n_distractors", "cameras"):
            assert meta[key] == again[key], key
    assert n_maps >= 4
    # the image itself (issue 60: every floor came back magenta, its texture left behind): the same pixels
    for d in _scenes(composed_dataset):
        for p in sorted(d.glob("rgb*.png")):
            a, b = (np.asarray(Image.open(x).convert("RGB"), dtype=np.float64) for x in (p, out / "scenes" / d.name / p.name))
            mse = float(((a - b) ** 2).mean())
            assert mse == 0.0 or 10 * np.log10(255.0 ** 2 / mse) >= 40.0, (d.name, p.name, mse)
            assert magenta_pixels(b) == 0 == magenta_pixels(a), (d.name, p.name)
        assert sorted(x.name for x in (d / "textures").iterdir()) == \
            sorted(x.name for x in (out / "scenes" / d.name / "textures").iterdir())
    src_gt, new_gt = (json.loads((x / "annotations" / "instances_train.json").read_text()) for x in (composed_dataset, out))
    assert src_gt["annotations"] == new_gt["annotations"] and len(src_gt["images"]) == len(new_gt["images"])


def magenta_pixels(rgb: np.ndarray) -> int:
    """Pixels of Blender's missing-texture magenta under any light: R and B alike and both well above G."""
    x = np.asarray(rgb, dtype=np.float64)[..., :3]
    r, g, b = x[..., 0], x[..., 1], x[..., 2]
    lift = np.minimum(r, b) - g
    return int(((lift > 15) & (np.abs(r - b) < 0.3 * lift)).sum())


def test_magenta_detector_sees_lit_magenta_and_not_pink_or_grey() -> None:
    lit = np.array([[[108, 27, 102], [234, 200, 236], [255, 0, 255]]])  # a re-render's floors, shaded
    other = np.array([[[230, 120, 160], [128, 128, 128], [40, 160, 40], [150, 60, 220]]])  # pink, grey, green, violet
    assert magenta_pixels(lit) == 3 and magenta_pixels(other) == 0


@pytest.mark.blender
def test_a_deleted_floor_texture_is_one_line_naming_it(composed_dataset: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    src = tmp_path / "copy"
    (src / "scenes").mkdir(parents=True)
    (src / "assets").symlink_to((composed_dataset / "assets").resolve())
    for d in _scenes(composed_dataset):
        shutil.copytree(d, src / "scenes" / d.name, symlinks=True)
    victim = sorted((src / "scenes").glob("scene_*/textures/*.png"))[-1]
    victim.unlink()
    out = tmp_path / "again"
    rc = main(["--config", "quick", "render", str(src), "--out", str(out), "--views", "0"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert str(victim) in err and "is missing" in err and "Traceback" not in err
    assert not out.exists()  # checked before anything was written


def _reference_check(d: Path, image_id: int, suffix: str, v_t: float) -> int:
    """Every annotation of one view against the one-render-per-object reference (as the compose tests do)."""
    from pycocotools import mask as mask_util

    coco = json.loads((d / "coco.json").read_text())
    inst = np.array(Image.open(d / f"instance{suffix}.png"))
    oracle = np.load(d / f"oracle_masks{suffix}.npz")
    h, w = oracle["shape"]
    anns = [a for a in coco["annotations"] if a["image_id"] == image_id]
    for a in anns:
        vis = mask_util.decode(a["segmentation"]).astype(bool)
        om = np.unpackbits(oracle[f"oracle_{a['instance_id']}"])[: h * w].reshape(h, w).astype(bool)
        assert vis.sum() / (om | vis).sum() >= 1.0 - v_t, (d.name, image_id, a["id"])
        assert np.array_equal(vis, inst == a["instance_id"])
        x, y = a["point"]
        assert inst[y, x] == a["instance_id"]
    return len(anns)


@pytest.mark.blender
@pytest.mark.slow
def test_new_views_under_both_rules_pass_the_reference_check(composed_dataset: Path, tmp_path: Path) -> None:
    for rule in ("all_cameras", "per_view"):
        out = tmp_path / rule
        summary = _render(composed_dataset, out, "--views", "2", "--samples", "1", "--rule", rule, "--oracle")
        written = [s for s in summary["scenes"] if s["status"] == "written"]
        assert written and all(s["views"] >= 3 for s in written)
        d = out / "scenes" / written[0]["scene_id"]
        meta = json.loads((d / "metadata.json").read_text())
        coco = json.loads((d / "coco.json").read_text())
        assert len(coco["images"]) == len(meta["cameras"]) == written[0]["views"]
        assert [c["framing"]["rule"] for c in meta["cameras"][-2:]] == ["paper camera rule (rerender)"] * 2
        per_view = []
        for k in range(len(meta["cameras"])):
            per_view.append(_reference_check(d, k + 1, "" if k == 0 else f"_cam_{k}", meta["visibility_threshold"]))
        if rule == "all_cameras":  # the paper's rule: every view lists the same kept objects
            assert len(set(per_view)) == 1
        kept = {o["instance_id"]: o["object_id"] for o in meta["objects"] if o["status"] == "kept"}
        for a in coco["annotations"]:  # one id per object in every view
            assert a["instance_id"] in kept
        merged = json.loads((out / "annotations" / "instances_train.json").read_text())
        assert len(merged["images"]) == sum(s["views"] for s in written)


@pytest.mark.blender
@pytest.mark.slow
def test_orbit_keeps_one_id_per_object_across_frames(composed_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "orbit"
    summary = _render(composed_dataset, out, "--trajectory", "orbit", "--frames", "6", "--resolution", "32",
                      "--samples", "1", "--rule", "per_view")
    d = out / "scenes" / summary["scenes"][0]["scene_id"]
    meta = json.loads((d / "metadata.json").read_text())
    orbit = [c for c in meta["cameras"] if c["framing"]["framing"] == "orbit"]
    assert [c["framing"]["frame"] for c in orbit] == list(range(6))
    centre = np.array(orbit[0]["framing"]["look_at"])
    dists = [np.linalg.norm(np.array(c["record"]["cam_to_world"])[:3, 3] - centre) for c in orbit]
    assert np.allclose(dists, orbit[0]["framing"]["distance"], rtol=1e-4)
    kept = {o["instance_id"] for o in meta["objects"] if o["status"] == "kept"}
    seen: dict[int, int] = {}
    for k in range(1, len(meta["cameras"])):
        ids = np.array(Image.open(d / f"instance_cam_{k}.png"))
        assert ids.shape == (32, 32)
        for i in set(np.unique(ids).tolist()) - {0}:
            seen[i] = seen.get(i, 0) + 1
    assert set(seen) <= kept and len(seen) >= len(kept) // 2
    assert max(seen.values()) == 6  # some object is tracked through every frame under its one id


@pytest.mark.blender
def test_gpu_on_a_machine_without_one_is_one_line_exit_2_nothing_written(composed_dataset: Path, tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "gpu"
    capsys.readouterr()
    assert main(["--config", "quick", "render", str(composed_dataset), "--out", str(out), "--device", "gpu"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "no usable GPU" in err[0] and "found CPU" in err[0] and "nothing was written" in err[0]
    assert not out.exists()


def test_paper_views_are_seeded_and_framed_on_the_pile() -> None:
    """The camera rule again around a pile (no bpy): same seed -> same cameras, another seed -> others;
    every camera looks at the pile and holds its origins."""
    from mixcount.config import load_config
    from mixcount.scene.framing import in_frame, pinhole
    from mixcount.scene.spec import CameraSpec
    from mixcount.scene.views import orbit_views, paper_views

    cfg = load_config(["quick"]).scene
    template = CameraSpec(name="cam_0", position=(0.0, -1.0, 1.0), look_at=(0.0, 0.0, 0.0),
                          orientation=(1.0, 0.0, 0.0, 0.0), elevation_deg=45.0, azimuth_deg=0.0, roll_deg=0.0,
                          distance=1.4, focal_length_mm=35.0, sensor_width_mm=36.0, sensor_height_mm=36.0,
                          resolution=(64, 64), clip_range=(0.01, 100.0), framing="paper",
                          lookat_offset=(0.0, 0.0, 0.0), distance_scale=1.0, distance_factor=1.5, fit_share=0.9)
    rng = np.random.default_rng(3)
    s = cfg.scale  # scene metres, as the sampler's jitters are
    pile = np.c_[rng.normal(0.0, 0.05 * s, (40, 2)), rng.uniform(0.0, 0.05 * s, 40)]
    sizes = np.full(40, 0.03 * s)
    a = paper_views(template, cfg, pile, sizes, None, k=4, seed=0, scene_seed=7, first_index=1)
    b = paper_views(template, cfg, pile, sizes, None, k=4, seed=0, scene_seed=7, first_index=1)
    c = paper_views(template, cfg, pile, sizes, None, k=4, seed=1, scene_seed=7, first_index=1)
    assert [v.name for v in a] == ["cam_1", "cam_2", "cam_3", "cam_4"]
    assert all(np.array_equal(x.cam_to_world, y.cam_to_world) for x, y in zip(a, b))
    assert not any(np.allclose(x.cam_to_world, y.cam_to_world) for x, y in zip(a, c))
    for v in a:
        cam = pinhole(template, v.cam_to_world[:3, 3], v.cam_to_world[:3, :3])
        assert in_frame(cam, pile, 0.0).mean() >= 0.9
        lo, hi = cfg.camera_elevation_deg
        assert lo - 1e-9 <= v.framing["elevation_deg"] <= hi + 1e-9
    orbit = orbit_views(template, pile, frames=8, elevation_deg=30.0, radius=2.0, start_azimuth_deg=10.0, first_index=1)
    centre = np.median(pile, axis=0)
    for v in orbit:
        pos = v.cam_to_world[:3, 3]
        assert np.linalg.norm(pos - centre) == pytest.approx(2.0)
        assert np.degrees(np.arcsin((pos[2] - centre[2]) / 2.0)) == pytest.approx(30.0)
        forward = -v.cam_to_world[:3, 2]  # looks down -Z at the centre
        assert np.allclose(forward, (centre - pos) / 2.0, atol=1e-9)
