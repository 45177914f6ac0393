"""RGB render time against image quality: Cycles settings measured on settled heavy stages vs a converged reference.

    .venv/bin/python bench/render_quality.py --quick --work W     # 2 stages, 256-spp reference (~25 min on 2 cores)
    .venv/bin/python bench/render_quality.py --work W             # 6 stages, 1024-spp reference (docs/performance.md)
    .venv/bin/python bench/render_quality.py --quick --try "b4:max_bounces=4,diffuse_bounces=2"   # one more setting
    .venv/bin/python bench/render_quality.py --smoke              # seconds: one tiny light stage (the suite)

Stages come from the heavy pool (bench/pools.py: captures of >= 200k faces, textures kept): with and without a
container, dark and over-bright light, bpy's bundled HDRIs and the procedural sky. Each stage is settled once
(physics, placement, visibility drops: the scene a user gets) and then rendered at its full resolution by
every setting in one bpy process (mixcount.engine.render_sweep), cam_0 only, rounds in the same order.

The reference of a stage is the same camera at the same resolution with many samples (``--reference-spp``),
deeper light paths than any candidate (16 bounces, 8 diffuse / glossy / transmission), adaptive sampling at
a 0.001 noise threshold (a converged pixel stops early; its minimum is a quarter of the samples), denoised
with OIDN's ACCURATE prefilter at HIGH quality, and another sampling seed than the candidates' (with the same
seed its first samples are theirs, which favours the settings that share its sample pattern). ``--reference-window F`` renders only the central F x F part
of the frame for it (quality is then measured there; the candidates still render the whole frame).

Settings: ``previous`` (the settings before issue 25: 32 spp, ACCURATE prefilter, adaptive sampling off,
8 / 3 / 3 / 4 / 8 bounces, light tree, HIGH), ``default`` (configs/default.toml now) and the single changes
and combinations of the candidate list. Per setting one JSON line: median RGB seconds per stage (``rgb_s``),
``psnr`` (dB) and ``ssim`` (Wang et al. 2004: Gaussian window sigma 1.5, 8-bit constants, mean over RGB)
against the reference. The last line holds ``previous`` and ``default`` with the ratio of their times and
whether the default is at least as close to the reference on every stage (PSNR at most 0.1 dB lower, SSIM
no lower).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

# label, seed, objects [lo, hi], container (True / False), config overrides of the light
STAGES = (
    ("tray_hdri", 12, 100, True, ["scene.environment_strength=[1.0,1.0]"]),
    ("open_sky_dark", 3, 100, False, ['scene.default_environment="sky"', "scene.environment_strength=[0.3,0.3]"]),
    ("bowl_hdri_bright", 1, 150, True, ["scene.environment_strength=[2.0,2.0]"]),
    ("open_hdri_dark", 10, 150, False, ["scene.environment_strength=[0.3,0.3]"]),
    ("plate_sky_bright", 2, 100, True, ['scene.default_environment="sky"', "scene.environment_strength=[2.0,2.0]"]),
    ("container_hdri_200", 5, 200, True, []),
)
QUICK_STAGES = ("tray_hdri", "open_sky_dark")

PREVIOUS: dict[str, Any] = {"samples": 32, "denoise_prefilter": "ACCURATE", "cycles": {}}  # over CYCLES_BEFORE
REFERENCE_CYCLES = {"max_bounces": 16, "diffuse_bounces": 8, "glossy_bounces": 8, "transmission_bounces": 8,
                    "transparent_max_bounces": 16, "adaptive_threshold": 0.001}
# single changes from `previous`, then combinations (each over CYCLES_BEFORE, 32 spp unless it says)
CANDIDATES: dict[str, dict[str, Any]] = {
    "prefilter_fast": {"denoise_prefilter": "FAST"},
    "oidn_balanced": {"cycles": {"denoising_quality": "BALANCED"}},
    "bounces_4": {"cycles": {"max_bounces": 4, "diffuse_bounces": 2, "glossy_bounces": 2, "transmission_bounces": 2,
                             "transparent_max_bounces": 4}},
    "no_light_tree": {"cycles": {"light_tree": False}},
    "adaptive_0.02_min8": {"cycles": {"adaptive_threshold": 0.02, "adaptive_min_samples": 8}},
}
QUICK_CANDIDATES = ("prefilter_fast",)


def parse_try(text: str) -> tuple[str, dict[str, Any]]:
    """``NAME:key=value,key=value`` -> a candidate over ``previous`` (samples / denoise_prefilter top level,
    the rest CyclesSpec fields)."""
    name, _, body = text.partition(":")
    cand: dict[str, Any] = {"cycles": {}}
    for item in filter(None, body.split(",")):
        key, _, raw = item.partition("=")
        value: Any = raw
        for cast in (int, float):
            try:
                value = cast(raw)
                break
            except ValueError:
                pass
        if raw in ("true", "false"):
            value = raw == "true"
        if key in ("samples", "denoise_prefilter"):
            cand[key] = value
        else:
            cand["cycles"][key] = value
    return name, cand


def candidate(name: str, over: dict[str, Any], base_cycles: dict[str, Any]) -> dict[str, Any]:
    """One render_sweep candidate: ``over`` applied on ``base_cycles`` (a full CyclesSpec dict)."""
    merged = {**PREVIOUS, **over}
    return {"name": name, "samples": int(merged["samples"]), "denoise_prefilter": merged["denoise_prefilter"],
            "cycles": {**base_cycles, **merged["cycles"]}}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM over the channels (Gaussian window sigma 1.5, K1 0.01, K2 0.03, L 255)."""
    from scipy.ndimage import gaussian_filter

    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    vals = []
    for ch in range(a.shape[2]):
        x, y = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)
        mx, my = gaussian_filter(x, 1.5), gaussian_filter(y, 1.5)
        sxx = gaussian_filter(x * x, 1.5) - mx * mx
        syy = gaussian_filter(y * y, 1.5) - my * my
        sxy = gaussian_filter(x * y, 1.5) - mx * my
        m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        vals.append(float(m[4:-4, 4:-4].mean()))  # the filter's border rows excluded
    return float(np.mean(vals))


def window(res: int, frac: float) -> tuple[list[float], tuple[slice, slice]]:
    """Blender's normalised border (x0, x1, y0, y1; y from the bottom) of the central ``frac`` of the frame,
    and the same pixels as array slices (rows top-down), on whole pixels."""
    n = int(round(res * frac))
    lo = (res - n) // 2
    return [lo / res, (lo + n) / res, lo / res, (lo + n) / res], (slice(res - lo - n, res - lo), slice(lo, lo + n))


def build_stage(label: str, seed: int, n: int, container: bool, extra: list[str], work: Path, pool: Any,
                resolution: int) -> tuple[Path, str]:
    """The stage's scene.usda (heavy assets converted, proxies as ingest makes them) and a hash of what it
    holds besides the render settings (two builds of the same scene have the same one)."""
    from pools import with_proxies

    from mixcount.config import load_config
    from mixcount.scene.sampler import sample_scene
    from mixcount.usd.stage import convert_scene_assets, write_stage

    cfg = load_config([], [f"compose.resolution={resolution}", f"scene.n_objects=[{n},{n}]",
                           f"scene.no_container_probability={0.0 if container else 1.0}", *extra])
    spec = sample_scene(seed, "train", cfg, pool)
    spec = with_proxies(spec, work / "proxies", cfg.ingest.proxy_max_vertices)
    convert_scene_assets(spec, work / "assets")
    out = work / "stages" / label
    out.mkdir(parents=True, exist_ok=True)
    write_stage(spec, work / "stages", assets_dir=work / "assets", scene_dir=out)
    scene = {k: v for k, v in spec.to_dict().items() if k not in ("render", "config_hash")}
    return out / "scene.usda", hashlib.sha256(json.dumps(scene, sort_keys=True).encode()).hexdigest()


def _arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 stages, one single change, 256-spp reference")
    ap.add_argument("--stages", default=None, help="comma-separated stage labels (default: all, or the quick two)")
    ap.add_argument("--resolution", type=int, default=1024)
    ap.add_argument("--reference-spp", type=int, default=None, help="reference samples (1024; --quick 256)")
    ap.add_argument("--reference-window", type=float, default=0.5,
                    help="reference renders the central F x F of the frame; quality measured there")
    ap.add_argument("--repeats", type=int, default=1, help="rounds of every setting per stage (median seconds)")
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    ap.add_argument("--only", default=None, help="comma-separated candidates of the list to run (besides "
                                                 "previous and default)")
    ap.add_argument("--try", dest="tries", action="append", default=[], metavar="NAME:key=v,...",
                    help="one more setting over previous (repeatable)")
    ap.add_argument("--reuse-reference", action="store_true",
                    help="keep a stage's reference from an earlier run into the same --work (same stage and settings)")
    ap.add_argument("--min-faces", type=int, default=200_000)
    ap.add_argument("--pool", default="heavy", help="heavy (captures' size, the default) or light (the demo library)")
    ap.add_argument("--objects", type=int, default=None, help="counted objects of every stage (default: the stage's)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--smoke", action="store_true", help="seconds: one light stage of 12 objects at 32 px, "
                                                         "previous and default only, 4-spp reference (the suite)")
    args = ap.parse_args()
    if args.smoke:
        args.quick, args.stages, args.pool, args.objects, args.resolution = True, "open_sky_dark", "light", 12, 32
        args.reference_spp, args.only, args.threads = 4, "", 1
    return args


def _settings(args: argparse.Namespace, cfg: Any, before: dict[str, Any]) -> tuple[dict[str, Any], dict[str, str]]:
    """``previous``, ``default``, the chosen candidates and ``--try`` ones; and each setting equal to an
    earlier one -> that one (rendered once: before the defaults change, ``default`` is ``previous``)."""
    names = (args.only.split(",") if args.only is not None else list(QUICK_CANDIDATES if args.quick else CANDIDATES))
    settings = {"previous": candidate("previous", PREVIOUS, before),
                "default": {"name": "default", "samples": cfg.compose.samples,
                            "denoise_prefilter": cfg.compose.denoise_prefilter, "cycles": cfg.cycles.to_dict()}}
    for n in filter(None, names):
        settings[n] = candidate(n, CANDIDATES[n], before)
    for t in args.tries:
        name, over = parse_try(t)
        settings[name] = candidate(name, over, before)
    same_as: dict[str, str] = {}
    order = list(settings)
    for name, setting in settings.items():
        twin = next((k for k in order[:order.index(name)] if k not in same_as
                     and {**settings[k], "name": ""} == {**setting, "name": ""}), None)
        if twin is not None:
            same_as[name] = twin
    return settings, same_as


def _reference(args: argparse.Namespace, before: dict[str, Any]) -> dict[str, Any]:
    spp = args.reference_spp or (256 if args.quick else 1024)
    ref = candidate("reference", {"samples": spp, "cycles": {**REFERENCE_CYCLES, "adaptive_min_samples": max(16, spp // 4)}},
                    before)
    ref["border"] = window(args.resolution, args.reference_window)[0] if args.reference_window < 1 else None
    ref["seed"] = 1  # not the candidates' seed 0: its first samples would be theirs
    ref["once"] = True
    return ref


def _sweep_stage(job: dict[str, Any], job_path: Path, label: str) -> dict[str, Any]:
    """Run mixcount.engine.render_sweep on ``job`` in its own bpy process; its sweep.json."""
    job_path.write_text(json.dumps(job))
    proc = subprocess.run([sys.executable, "-m", "mixcount.engine.render_sweep", str(job_path)],
                          cwd=str(ROOT), capture_output=True, text=True, timeout=6 * 3600)
    if proc.returncode != 0:
        print(proc.stdout[-3000:], proc.stderr[-3000:], file=sys.stderr)
        raise SystemExit(f"render sweep of stage {label} failed (rc {proc.returncode})")
    sweep: dict[str, Any] = json.loads((Path(job["out"]) / "sweep.json").read_text())
    return sweep


def main() -> int:
    args = _arguments()
    from PIL import Image
    from pools import load_pool

    from mixcount.config import load_config
    from mixcount.scene.spec import CYCLES_BEFORE
    from mixcount.worker.contract import SceneOutputs, SceneRequest

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-rq-"))
    threads = args.threads or os.cpu_count() or 1
    labels = (args.stages.split(",") if args.stages else list(QUICK_STAGES if args.quick else [s[0] for s in STAGES]))
    cfg = load_config()
    before = CYCLES_BEFORE.to_dict()
    settings, same_as = _settings(args, cfg, before)
    reference = _reference(args, before)
    _, (rows, cols) = window(args.resolution, args.reference_window)
    pool = load_pool(args.pool, work, min_faces=args.min_faces)
    per: dict[str, dict[str, list[float]]] = {k: {"rgb_s": [], "psnr": [], "ssim": []} for k in settings}
    stage_rows = []
    for label, seed, n, container, extra in STAGES:
        if label not in labels:
            continue
        n = args.objects or n
        stage, stage_hash = build_stage(label, seed, n, container, extra, work, pool, args.resolution)
        out = work / "renders" / label
        request = SceneRequest.for_outputs(SceneOutputs.from_config(cfg.compose), stage=str(stage),
                                           out_dir=str(stage.parent), threads=threads, oracle=False)
        # keyed by what shapes the reference image; ``once`` only schedules it (one round of --repeats)
        ref_key = {"scene_sha256": stage_hash, "reference": {k: v for k, v in reference.items() if k != "once"}}
        ref_json = out / "reference.json"
        reuse = (args.reuse_reference and ref_json.is_file() and (out / "reference.png").is_file()
                 and json.loads(ref_json.read_text())["key"] == ref_key)
        rendered = [v for k, v in settings.items() if k not in same_as]
        t0 = time.perf_counter()
        sweep = _sweep_stage({"request": request.to_dict(), "candidates": [*rendered, *([] if reuse else [reference])],
                              "repeats": args.repeats, "out": str(out)}, work / f"job_{label}.json", label)
        if not reuse:
            ref_json.write_text(json.dumps({"key": ref_key, "seconds": sweep["candidates"]["reference"]["seconds"][0]}))
        ref = np.asarray(Image.open(out / "reference.png").convert("RGB"))[rows, cols]
        stage_rows.append({"stage": label, "seed": seed, "objects": n, "container": container,
                           "counted_kept": sweep["counted_kept"], "distractors_kept": sweep["distractors_kept"],
                           "reference_s": json.loads(ref_json.read_text())["seconds"], "reference_reused": reuse,
                           "sweep_s": round(time.perf_counter() - t0, 1)})
        print(json.dumps(stage_rows[-1]), file=sys.stderr)
        for name in settings:
            src = same_as.get(name, name)
            img = np.asarray(Image.open(out / f"{src}.png").convert("RGB"))[rows, cols]
            per[name]["rgb_s"].append(round(statistics.median(sweep["candidates"][src]["seconds"]), 3))
            per[name]["psnr"].append(round(psnr(img, ref), 3))
            per[name]["ssim"].append(round(ssim(img, ref), 5))
            print(f"  {label:20s} {name:24s} {per[name]['rgb_s'][-1]:7.2f} s  PSNR {per[name]['psnr'][-1]:6.2f} dB"
                  f"  SSIM {per[name]['ssim'][-1]:.5f}", file=sys.stderr)
    _report(args, settings, per, stage_rows, before, threads)
    return 0


def _report(args: argparse.Namespace, settings: dict[str, Any], per: dict[str, dict[str, list[float]]],
            stage_rows: list[dict[str, Any]], before: dict[str, Any], threads: int) -> None:
    """One JSON line per setting, then the summary line (``previous`` and ``default``)."""
    for name, setting in settings.items():
        print(json.dumps({"setting": name, **per[name], "median_rgb_s": statistics.median(per[name]["rgb_s"]),
                          "time_vs_previous": round(statistics.median(
                              a / b for a, b in zip(per[name]["rgb_s"], per["previous"]["rgb_s"])), 3),
                          "samples": setting["samples"], "denoise_prefilter": setting["denoise_prefilter"],
                          "cycles_changed": {k: v for k, v in setting["cycles"].items() if before[k] != v}}))
    prev, new = per["previous"], per["default"]
    ratios = [a / b for a, b in zip(new["rgb_s"], prev["rgb_s"])]
    print(json.dumps({
        "bench": "render_quality", "quick": args.quick, "pool": args.pool, "resolution": args.resolution,
        "reference_spp": args.reference_spp or (256 if args.quick else 1024),
        "reference_window": args.reference_window, "threads": threads, "cpu_count": os.cpu_count(),
        "stages": stage_rows, "previous": prev, "default": new,
        "default_time_ratio": {"median": round(statistics.median(ratios), 3), "max": round(max(ratios), 3)},
        "default_as_close_on_every_stage": all(pn >= pp - 0.1 and sn >= sp for pn, pp, sn, sp in
                                               zip(new["psnr"], prev["psnr"], new["ssim"], prev["ssim"])),
        "default_cycles": settings["default"]["cycles"], "default_samples": settings["default"]["samples"],
        "default_denoise_prefilter": settings["default"]["denoise_prefilter"]}))


if __name__ == "__main__":
    sys.exit(main())
