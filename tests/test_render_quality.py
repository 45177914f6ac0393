"""The RGB render's Cycles settings: recorded in the spec, validated, applied by the worker, and the
render-quality bench (bench/render_quality.py) measuring them against a reference on a real bpy stage."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT / "bench"))


def test_cycles_settings_round_trip_and_old_specs_read_as_before() -> None:
    import dataclasses

    from mixcount.config import load_config
    from mixcount.scene.spec import CYCLES_BEFORE, CyclesSpec, RenderSpec

    cfg = load_config()
    render = RenderSpec(resolution=64, samples=8, denoise=True, visibility_threshold=0.4,
                        denoise_prefilter="FAST", cycles=cfg.cycles)
    assert RenderSpec.from_dict(json.loads(json.dumps(render.to_dict()))) == render
    old = render.to_dict()
    del old["cycles"]  # a stage written before [cycles] existed renders as it did then
    assert RenderSpec.from_dict(old).cycles == CYCLES_BEFORE
    assert CYCLES_BEFORE.max_bounces == 8 and CYCLES_BEFORE.adaptive_threshold == 0.0
    with pytest.raises(ValueError, match="unknown Cycles setting"):
        CyclesSpec.from_dict({**cfg.cycles.to_dict(), "max_bounce": 3})
    partial = cfg.cycles.to_dict()
    del partial["light_tree"]
    with pytest.raises(ValueError, match=r"lacks setting\(s\) \['light_tree'\]"):
        CyclesSpec.from_dict(partial)
    from mixcount.errors import ConfigError

    with pytest.raises(ConfigError, match="cycles.denoising_quality"):
        dataclasses.replace(cfg.cycles, denoising_quality="BEST").validate()
    with pytest.raises(ConfigError, match="cycles.diffuse_bounces must be >= 0"):
        load_config([], ["cycles.diffuse_bounces=-1"])
    with pytest.raises(ConfigError, match="cycles.adaptive_threshold must be < 1"):
        load_config([], ["cycles.adaptive_threshold=2.0"])


def test_image_metrics_and_reference_window() -> None:
    from render_quality import parse_try, psnr, ssim, window

    rng = np.random.default_rng(0)
    a = rng.integers(0, 255, (64, 64, 3)).astype(np.uint8)
    assert psnr(a, a) == float("inf") and ssim(a, a) == pytest.approx(1.0)
    b = a.astype(np.int16) + 1
    b[b > 255] = 254
    assert psnr(a, b.astype(np.uint8)) == pytest.approx(10 * np.log10(255 ** 2), abs=0.05)
    noisy = np.clip(a + rng.normal(0, 20, a.shape), 0, 255).astype(np.uint8)
    noisier = np.clip(a + rng.normal(0, 40, a.shape), 0, 255).astype(np.uint8)
    assert 1 > ssim(a, noisy) > ssim(a, noisier) and psnr(a, noisy) > psnr(a, noisier)
    border, (rows, cols) = window(100, 0.5)  # the central half: pixels 25..74 both ways
    assert border == [0.25, 0.75, 0.25, 0.75] and (rows, cols) == (slice(25, 75), slice(25, 75))
    name, cand = parse_try("b4:max_bounces=4,light_tree=false,samples=24,denoise_prefilter=FAST")
    assert name == "b4" and cand == {"samples": 24, "denoise_prefilter": "FAST",
                                     "cycles": {"max_bounces": 4, "light_tree": False}}


@pytest.mark.blender
def test_render_quality_bench_on_a_real_stage(tmp_path: Path) -> None:
    """The bench end to end at 48 px on 8 objects of the light pool: one stage settled once and rendered with
    `previous`, `default`, a single change and the reference (a window of it); every setting is applied as
    asked (read back from Cycles) and compared with the reference."""
    cmd = [sys.executable, str(PROJECT_ROOT / "bench" / "render_quality.py"), "--pool", "light", "--objects", "8",
           "--resolution", "48", "--reference-spp", "16", "--reference-window", "0.5", "--stages", "tray_hdri",
           "--only", "bounces_4", "--try", "few:samples=2", "--threads", "2", "--work", str(tmp_path)]
    proc = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [json.loads(x) for x in proc.stdout.splitlines() if x.startswith("{")]
    final, settings = lines[-1], {x["setting"]: x for x in lines[:-1]}
    assert set(settings) == {"previous", "default", "bounces_4", "few"}
    for key in ("previous", "default"):
        assert len(final[key]["rgb_s"]) == len(final[key]["psnr"]) == len(final[key]["ssim"]) == 1
        assert final[key]["rgb_s"][0] > 0 and 10 < final[key]["psnr"][0] < 80 and 0 < final[key]["ssim"][0] <= 1
    # 2 samples are further from the 16-sample reference than 32
    assert settings["few"]["psnr"][0] < settings["previous"]["psnr"][0]
    sweep = json.loads((tmp_path / "renders" / "tray_hdri" / "sweep.json").read_text())
    applied = {k: v["applied"] for k, v in sweep["candidates"].items()}
    assert applied["bounces_4"]["max_bounces"] == 4 and applied["previous"]["max_bounces"] == 8
    assert applied["few"]["samples"] == 2 and applied["reference"]["use_adaptive_sampling"]
    assert applied["default"]["samples"] == final["default_samples"]
    assert applied["reference"]["seed"] == 1 and applied["previous"]["seed"] == 0  # not the candidates' samples
    assert sweep["candidates"]["reference"]["border"] == [0.25, 0.75, 0.25, 0.75]  # its central window only
    assert sweep["candidates"]["previous"]["border"] is None
    # a second run reuses the stage's reference (same scene, same reference settings) and renders the rest
    proc = subprocess.run([*cmd, "--reuse-reference"], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    again = json.loads(proc.stdout.splitlines()[-1])
    assert again["stages"][0]["reference_reused"] and "reference" not in json.loads(
        (tmp_path / "renders" / "tray_hdri" / "sweep.json").read_text())["candidates"]
    # the same scene rendered the same way (Cycles + OIDN are not bit-exact between runs)
    assert again["previous"]["psnr"][0] == pytest.approx(final["previous"]["psnr"][0], abs=0.5)
