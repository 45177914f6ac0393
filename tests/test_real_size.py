"""Real-size scenes (issue 70 item 2): ``[scene] size_rule = "real"``.

The sampler's side on records (fast): every class at its real size times the jitter, distractors and the
container at real size, the scene scale chosen per scene (the classes in the paper's range), no resized
pair, untrusted sizes refused in one line, the paper's specs unchanged; the ``pile`` framing's distance.
Then one quick-config compose by real bpy on a library of parts of very different sizes (beads stated 8 mm
and 24 mm, one file, a 20 cm box as distractor): the rendered masks keep their proportions (median mask
area ratio against the real size ratio squared) and no body is lost."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image
from sqlalchemy import select

from mixcount.catalog.db import open_catalog
from mixcount.catalog.models import CatalogObject, Split
from mixcount.cli import main
from mixcount.config import load_config
from mixcount.errors import CompositionError
from mixcount.scene.framing import frame_camera
from mixcount.scene.object_records import ObjectRecord, fallback_captions
from mixcount.scene.sampler import sample_scene, scene_scale, size_warning

REAL = ['scene.size_rule="real"']


def rec(i: int, name: str, cat: str, dims: tuple[float, float, float], src: str | None = "model",
        container: bool = False) -> ObjectRecord:
    return ObjectRecord(object_id=i, name=name, category=cat, dims=dims, captions=fallback_captions(name, cat),
                        split="train", model_path=f"/lib/{i}.glb", content_hash=f"h{i}", container=container,
                        size_source=src)


POOL = [rec(1, "Resistor 0805", "resistor", (0.002, 0.00125, 0.0005)), rec(2, "LED 5mm", "led", (0.0058, 0.0058, 0.0086)),
        rec(3, "Capacitor", "capacitor", (0.005, 0.005, 0.011), src="kind"), rec(4, "DIP-8 IC", "ic", (0.0098, 0.0064, 0.0045)),
        rec(5, "Parts tray", "tray", (0.12, 0.08, 0.015), src="stated", container=True),
        rec(6, "Buzzer", "buzzer", (0.012, 0.012, 0.0095)), rec(7, "Crate", "crate", (0.5, 0.3, 0.3)),
        rec(8, "Unit cube dragon", "dragon", (1.0, 0.7, 0.4), src="none"), rec(9, "Old object", "widget", (0.05, 0.05, 0.05), src=None)]
BY_ID = {o.object_id: o for o in POOL}


@pytest.fixture(scope="module")
def real_cfg():
    return load_config(overrides=REAL)


def test_every_object_keeps_its_real_size_and_the_scale_is_chosen_per_scene(real_cfg):
    cfg = real_cfg
    lo, hi = (v * cfg.scene.scale for v in cfg.scene.class_size)
    scales, seen_container = set(), 0
    for seed in range(40):
        spec = sample_scene(seed, "train", cfg, POOL)
        s = spec.scale
        scales.add(s)
        assert spec.size_rule == "real"
        real = [BY_ID[c.object_id].max_dim for c in spec.classes]
        assert s == scene_scale(real, cfg.scene)
        assert min(real) * s >= lo * (1 - 1e-3)  # the smallest class at least the paper's smallest
        for c in spec.classes:
            assert c.construction != "same_object_resized" and c.size_qualifier is None
            assert c.target_size_m == pytest.approx(BY_ID[c.object_id].max_dim * s, rel=1e-5)
        for o in spec.objects:
            ratio = o.size_m / spec.classes[o.class_index].target_size_m
            assert cfg.scene.instance_jitter[0] - 1e-6 <= ratio <= cfg.scene.instance_jitter[1] + 1e-6
        for d in spec.distractors:
            assert d.size_m == pytest.approx(BY_ID[d.object_id].max_dim * s, rel=1e-5)
        if spec.container is not None:
            seen_container += 1
            assert spec.container.pile_fit == 1.0
            assert np.allclose(np.asarray(spec.container.extent_m) / s, BY_ID[spec.container.object_id].dims, rtol=1e-5)
            assert {c.framing for c in spec.cameras} == {"pile"} and spec.cameras[0].pile_area == pytest.approx(
                math.sqrt(cfg.scene.container_pile_area[0] * cfg.scene.container_pile_area[1]), rel=1e-5)
        # every other length is the paper's (·s of scene.scale): physics sees a paper scene
        assert spec.physics.rest_speed == pytest.approx(cfg.scene.physics_rest_speed * cfg.scene.scale, rel=1e-5)
        assert spec.floor.thickness == pytest.approx(cfg.scene.floor_thickness * cfg.scene.scale, rel=1e-4)
        # a body larger than the spawn range's low end (the 0.5 m crate beside 2 mm resistors: 112 m) never
        # starts inside the floor or the tray, and the floor collider is never shallower than the largest body
        base = spec.container.extent_m[2] if spec.container is not None else 0.0
        assert all(o.position[2] - o.size_m / 2 >= base - 1e-6 for o in spec.objects)
        assert spec.physics.floor_collider_depth >= max(o.size_m for o in spec.objects) - 1e-6
        used = {c.object_id for c in spec.classes} | {d.object_id for d in spec.distractors}
        assert not used & {8, 9}  # no trustworthy size: never drawn
        assert json.loads(spec.to_json())["size_rule"] == "real"
    assert len(scales) > 5 and seen_container > 10


def test_untrusted_sizes_are_refused_in_one_line(real_cfg):
    line = size_warning(POOL, "train", real_cfg.scene)
    assert line is not None and "\n" not in line
    assert line.startswith("2 object(s) of split 'train' have no trustworthy real size")
    assert "Unit cube dragon (none)" in line and "Old object (not recorded)" in line and '"size": "14 mm"' in line
    assert size_warning(POOL, "train", load_config().scene) is None
    with pytest.raises(CompositionError, match="trustworthy real size"):
        sample_scene(0, "train", real_cfg, [o for o in POOL if o.object_id in (8, 9)])


def test_the_paper_rule_is_unchanged():
    spec = sample_scene(3, "train", load_config(), POOL)
    text = spec.to_json()
    assert spec.size_rule is None and '"size_rule"' not in text and '"pile_area"' not in text and spec.scale == 10.0
    lo, hi = (v * 10.0 for v in load_config().scene.class_size)
    assert all(lo <= c.target_size_m <= hi for c in spec.classes)


def test_pile_framing_shows_the_paper_pixels_per_object(real_cfg):
    """The pile rule puts the camera where a paper scene's container, fitted to the pile at the middle of
    container_pile_area, would: 1.2 x its diagonal x the drawn jitter."""
    spec = next(sp for sp in (sample_scene(seed, "train", real_cfg, POOL) for seed in range(20))
                if sp.container is not None)
    cam = spec.cameras[0]
    rng = np.random.default_rng(0)
    sizes = np.full(50, 0.6)
    pts = np.c_[rng.uniform(-2, 2, (50, 2)), np.full(50, 0.3)]
    framed = frame_camera(cam, pts, sizes, 1.7, margin=0.02)
    expected = cam.distance_factor * math.sqrt(2 * cam.pile_area * 50 * 0.36) * cam.distance_scale
    assert framed.camera.distance == pytest.approx(expected, rel=1e-5)
    assert framed.derivation["framing"] == "pile" and "footprint" in framed.derivation["distance_rule"]
    # parts spread over a tray far larger than their pile: never closer than the fit (they stay in the frame)
    wide = np.c_[rng.uniform(-20, 20, (50, 2)), np.full(50, 0.3)]
    spread = frame_camera(cam, wide, sizes, 1.7, margin=0.02)
    assert spread.camera.distance == pytest.approx(spread.derivation["fit_distance"], rel=1e-5)
    assert spread.camera.distance > expected
    inside = int(spread.derivation["counted_origins_in_frame"].split("/")[0])
    assert inside >= math.ceil(cam.fit_share * 50)


# ------------------------------------------------------------------------------------------- rendered

# the two beads are one file (one unit-cube model given two sizes): one asset each all the same
BEADS = {"Small bead": ("8 mm", (0.9, 0.15, 0.1)), "Large bead": ("24 mm", (0.9, 0.15, 0.1)),
         "Storage box": ("20 cm", (0.8, 0.8, 0.8))}


def _library(root: Path) -> Path:
    for name, (size, colour) in BEADS.items():
        folder = root / name
        folder.mkdir(parents=True)
        mesh = trimesh.creation.box(extents=(1.0, 0.6, 0.4)) if "box" in name else \
            trimesh.creation.icosphere(subdivisions=1, radius=0.5)
        mesh.visual.face_colors = [int(255 * c) for c in colour] + [255]
        mesh.export(folder / "model.glb")
        (folder / "metadata.json").write_text(json.dumps({"size": size, "category": name.split()[-1]}))
    return root


@pytest.mark.blender
def test_a_real_size_compose_keeps_the_proportions_in_the_masks(tmp_path: Path, capsys) -> None:
    lib = _library(tmp_path / "lib")
    db = tmp_path / "catalog.db"
    assert main(["--db", str(db), "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    cat = open_catalog(str(db), data_dir="")
    with cat.session() as s:
        for obj in s.scalars(select(CatalogObject)):
            s.add(Split(object_id=obj.id, split="train", method="random"))
        s.commit()
    cat.close()
    out = tmp_path / "out"
    args = ["--db", str(db), "--config", "quick", "--set", 'scene.size_rule="real"', "--set", "scene.n_objects=[14,14]",
            "--set", "scene.n_classes=[2,2]", "--set", "scene.n_distractors=[1,1]",
            "--set", "scene.no_container_probability=1.0", "--set", 'scene.counted_exclude_categories=["box"]',
            "compose", "--n", "1", "--split", "train", "--seed", "2", "--resolution", "160", "--samples", "1",
            "--out", str(out)]
    capsys.readouterr()
    assert main(args) == 0, capsys.readouterr().err
    (d,) = sorted((out / "scenes").glob("scene_*"))
    meta = json.loads((d / "metadata.json").read_text())
    counted = [o for o in meta["objects"] if o["role"] == "counted"]
    lost = [o for o in meta["objects"] if o.get("reason") in ("below_floor", "flung_out", "unstable", "interpenetration")]
    assert not lost, lost
    ids = np.array(Image.open(d / "instance.png"))
    area = {int(i): int(n) for i, n in zip(*np.unique(ids, return_counts=True)) if i}
    classes = {c["class_index"]: c for c in meta["spec"]["classes"]}
    by_size = {}
    for ci in classes:
        kept = [area[o["instance_id"]] for o in counted if o["class_index"] == ci and o["status"] == "kept"
                and o["instance_id"] in area]
        assert len(kept) >= 2, (ci, kept)
        by_size[round(classes[ci]["target_size_m"] / meta["spec"]["scale"], 4)] = float(np.median(kept))
    (small, a_small), (large, a_large) = sorted(by_size.items())
    assert (small, large) == (0.008, 0.024)
    ratio = a_large / a_small
    print(f"median mask areas {a_small:.0f} / {a_large:.0f} px: ratio {ratio:.2f} against (24/8)^2 = 9")
    assert 9 / 1.6 <= ratio <= 9 * 1.6
    dist = [o for o in meta["objects"] if o["role"] == "distractor"]
    assert dist and all(o["size_m"] / meta["spec"]["scale"] == pytest.approx(0.2, rel=1e-4) for o in dist)
