"""Every bench in bench/ runs in its ``--smoke`` mode (tiny sizes, the same code path) and prints
well-formed figures: the keys the docs quote are present and every number is finite. A bench that no
longer runs (a renamed parameter, a moved module) fails here instead of on the day someone needs it.

The benches that draw scenes share the session's seed-0 demo library and one folder of converted assets and
proxies (each bench gets its own work folder with links to them). bench/curation.py --smoke generates, renders
and filters its own small demo library (8 ordinary objects and every trap, 16 px): a cold filter of the whole
library is tests/test_curate_demo.py's work, and repeating it here cost 90 s of the suite (issue 58)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench"
SHARED = ("demo", "assets", "proxies")  # what the scene benches reuse under --work (content-addressed)


def _numbers(value: Any, where: str = "") -> list[tuple[str, float]]:
    """Every number in a JSON value with its path (booleans are not numbers)."""
    if isinstance(value, bool):
        return []
    if isinstance(value, (int, float)):
        return [(where, float(value))]
    if isinstance(value, dict):
        return [n for k, v in value.items() for n in _numbers(v, f"{where}.{k}")]
    if isinstance(value, list):
        return [n for i, v in enumerate(value) for n in _numbers(v, f"{where}[{i}]")]
    return []


def _get(doc: dict[str, Any], dotted: str) -> Any:
    """``doc["a"]["b"][0]`` for ``"a.b.0"``; a KeyError / IndexError names what is missing."""
    value: Any = doc
    for part in dotted.split("."):
        value = value[int(part)] if isinstance(value, list) else value[part]
    return value


@pytest.fixture(scope="module")
def bench_root(tmp_path_factory: pytest.TempPathFactory, demo_library: tuple[Path, dict]) -> Path:
    """A folder linking the session's seed-0 demo library (what the benches generate into ``WORK/demo``)
    and holding the assets and proxies the benches share; each bench links to them from its work folder."""
    root = tmp_path_factory.mktemp("benches")
    (root / "shared").mkdir()
    (root / "shared" / "demo").symlink_to(demo_library[0], target_is_directory=True)
    for name in SHARED[1:]:
        (root / "shared" / name).mkdir()
    return root


def run_smoke(name: str, root: Path | None, *, share: bool = True, args: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Run ``bench/<name>.py --smoke [args]`` in a child process (``--work root/name``, linked to the shared demo
    library when ``share``; no --work when ``root`` is None); the JSON lines it printed on stdout."""
    cmd = [sys.executable, str(BENCH / f"{name}.py"), "--smoke", *args]
    if root is not None:
        folder = root / name
        folder.mkdir(exist_ok=True)
        for shared in SHARED if share else ():
            (folder / shared).symlink_to(root / "shared" / shared, target_is_directory=True)
        cmd += ["--work", str(folder)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"bench/{name}.py --smoke exited {done.returncode}:\n{done.stderr[-4000:]}"
    lines = [json.loads(ln) for ln in done.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"bench/{name}.py --smoke printed no JSON line:\n{done.stdout[-2000:]}"
    return lines


def check_figures(doc: dict[str, Any], keys: list[str]) -> None:
    """``keys`` (dotted paths) are present and numbers; every number in ``doc`` is finite."""
    for key in keys:
        value = _get(doc, key)
        assert isinstance(value, (int, float)) and not isinstance(value, bool), f"{key} = {value!r} is not a number"
    bad = [(where, v) for where, v in _numbers(doc) if not math.isfinite(v)]
    assert not bad, f"figures that are not finite: {bad}"


@pytest.mark.blender
def test_compose_bench(bench_root: Path) -> None:
    doc = run_smoke("compose", bench_root)[-1]
    assert doc["bench"] == "compose" and len(doc["scenes"]) == 1
    scene = doc["scenes"][0]
    assert "error" not in scene, scene
    check_figures(doc, ["scenes.0.counted_kept", "scenes.0.seconds.physics", "scenes.0.seconds.rgb",
                        "scenes.0.seconds.whole", "scenes.0.whole_over_rgb", "scenes.0.physics_share",
                        "scenes.0.bytes.total"])
    assert scene["counted_kept"] > 0 and scene["seconds"]["whole"] >= scene["seconds"]["rgb"] > 0


@pytest.mark.blender
def test_visibility_bench(bench_root: Path) -> None:
    doc = run_smoke("visibility", bench_root)[-1]
    assert doc["bench"] == "visibility" and len(doc["scenes"]) == 1 and "error" not in doc["scenes"][0]
    check_figures(doc, ["scenes.0.filter_s", "scenes.0.rgb_s", "scenes.0.scene_s", "scenes.0.filter_over_scene",
                        "max_filter_over_scene"])
    assert 0 < doc["scenes"][0]["filter_over_scene"] < 1


@pytest.mark.blender
def test_settle_bench(bench_root: Path) -> None:
    rows = run_smoke("settle", bench_root)
    assert [r["seed"] for r in rows] == [0] and rows[0]["bench"] == "settle"
    check_figures(rows[0], ["objects", "frames_run", "physics_s", "counted_kept", "spawn_max_z",
                            "median_settle_distance_m"])
    assert 0 < rows[0]["frames_run"] <= 60


@pytest.mark.blender
def test_density_bench(bench_root: Path) -> None:
    rows = run_smoke("density", bench_root)
    assert [r["pool"] for r in rows] == ["light"] and rows[0]["scenes"] == 1 and rows[0]["failed"] == []
    check_figures(rows[0], ["counted_spawned", "counted_kept", "retention", "mean_counted_kept",
                            "distractors_kept", "lost_off_floor_share"])
    assert 0 < rows[0]["retention"] <= 1


@pytest.mark.blender
def test_counts_bench(bench_root: Path) -> None:
    """Two light-pool scenes with a count target, real bpy (issue 37): both kept exactly their target,
    every class on its drawn count, surplus bodies taken out; then the paper's rule on the same seeds."""
    lines = run_smoke("counts", bench_root)
    target, paper, ratio = lines
    assert target["counts"] == "uniform:3-8,imbalance:1-2" and target["scenes_kept"] == 2 and target["failed"] == []
    check_figures(target, ["seconds_per_kept_scene", "physics_s_per_scene", "rgb_s_per_scene", "ks_distance",
                           "exact_share", "bins.kept.0", "per_class.max_off", "spawned_per_target"])
    assert target["exact"] == 2 and target["per_class"]["max_off"] == 0 and target["surplus_removed"] > 0
    assert paper["run"] == "paper" and paper["scenes_kept"] == 2 and ratio["target_over_paper"] > 0
    for run in (target, paper):  # how the scenes look (issue 48): figures of instance.png and rgb.png
        check_figures(run, ["image_share_median", "visible_px_median", "union_box_median", "luminance_median"])
        assert 0 < run["image_share_median"] <= run["union_box_median"] <= 1 and 0 < run["luminance_median"] < 1


@pytest.mark.blender
def test_throughput_bench(bench_root: Path) -> None:
    doc = run_smoke("throughput", bench_root)[-1]
    assert doc["bench"] == "throughput" and [r["executor"] for r in doc["runs"]] == ["local"]
    check_figures(doc, ["runs.0.wall_s", "runs.0.scenes_per_hour", "runs.0.cpu_s_per_scene", "runs.0.written"])
    assert doc["runs"][0]["written"] == doc["scenes"] == 2 and doc["runs"][0]["failed"] == 0


@pytest.mark.blender
def test_render_quality_bench(bench_root: Path) -> None:
    lines = run_smoke("render_quality", bench_root)
    doc = lines[-1]
    assert doc["bench"] == "render_quality" and [s["stage"] for s in doc["stages"]] == ["open_sky_dark"]
    assert {ln["setting"] for ln in lines[:-1]} == {"previous", "default"}
    check_figures(doc, ["stages.0.reference_s", "previous.rgb_s.0", "previous.psnr.0", "previous.ssim.0",
                        "default.rgb_s.0", "default.psnr.0", "default.ssim.0", "default_time_ratio.median"])
    assert 0 < doc["default"]["ssim"][0] <= 1 and doc["default"]["psnr"][0] > 0


@pytest.mark.blender
def test_merge_bench(bench_root: Path) -> None:
    doc = run_smoke("merge", bench_root)[-1]
    assert doc["bench"] == "merge" and [r["scenes"] for r in doc["rows"]] == [3, 10]
    check_figures(doc, ["objects_per_scene", "annotations_per_scene", "rows.0.cold.seconds",
                        "rows.0.cold.peak_rss_mb", "rows.1.warm_plus_one.seconds", "rows.1.us_per_scene_cold"])
    assert doc["annotations_per_scene"] > 0


@pytest.mark.blender
def test_passes_bench(bench_root: Path) -> None:
    doc = run_smoke("passes", bench_root)[-1]
    assert doc["bench"] == "passes" and doc["shape"] == [32, 32]
    from mixcount.annotate.passes import DEPTH_FORMATS, NORMAL_FORMATS

    assert set(doc["depth"]) == set(DEPTH_FORMATS) and set(doc["normal"]) == set(NORMAL_FORMATS)
    check_figures(doc, [f"depth.{f}.bytes" for f in DEPTH_FORMATS] + [f"depth.{f}.max_rel_err" for f in DEPTH_FORMATS]
                  + [f"normal.{f}.max_err_deg" for f in NORMAL_FORMATS] + ["surface_fraction"])
    assert all(d["surface_mask_kept"] for d in doc["depth"].values())


@pytest.mark.blender
def test_curation_bench(tmp_path: Path) -> None:
    # its own small demo library (8 ordinary objects and every trap, 16 px): tests/test_curate_demo.py filters the whole one
    doc = run_smoke("curation", tmp_path, share=False)[-1]
    arm = doc["arms"][0]
    check_figures(doc, ["arms.0.objects", "arms.0.median_cold_wall_s", "arms.0.median_warm_wall_s",
                        "arms.0.precision", "arms.0.recall", "arms.0.clean_flag_rate"])
    assert doc["reps"] == 1 and arm["objects"] > 0 and arm["by_trap"]


@pytest.mark.blender
def test_rerender_bench(bench_root: Path, demo_catalog_copy) -> None:
    demo_catalog_copy(bench_root / "rerender" / "cat", 12)  # the 12-object catalog it builds in work/cat: the session's
    doc = run_smoke("rerender", bench_root)[-1]
    assert doc["bench"] == "rerender" and doc["views"] == 3
    check_figures(doc, ["total_s", "fresh.seconds", "views_persistent.first_view_s", "views_persistent.view_s.2",
                        "later_over_first_median", "fresh_over_view_median", "rgb_persistent_over_not_median"])
    assert len(doc["later_over_first"]) == 2 and doc["fresh_over_view_median"] > 0


@pytest.mark.slow  # about 10 s each: kept out of make test-fast
def test_capture_bench() -> None:
    doc = run_smoke("capture", None)[-1]
    check_figures(doc, ["ingest_s", "filter_s", "peak_rss_mb", "faces.0"])
    assert doc["broken"] == 0 and len({tuple(p[:2]) for p in doc["pairs"]}) == 6  # the four are one group


@pytest.mark.slow
def test_candidates_bench() -> None:
    doc = run_smoke("candidates", None)[-1]
    check_figures(doc, ["sizes.0.index_s", "sizes.1.index_s", "sizes.1.pairs", "sizes.0.align_s_per_pair"])
    assert all(r["copies_found"] >= 0.9 * r["copies"] and r["pairs"] < r["all_pairs"] / 4 for r in doc["sizes"])


@pytest.mark.slow
def test_ingest_bench() -> None:
    doc = run_smoke("ingest", None)[-1]
    check_figures(doc, ["objects", "first_s", "first_obj_per_s", "rerun_s", "rerun_obj_per_s", "ratio"])
    assert doc["subdivide"] == 0 and doc["objects"] > 0 and doc["rerun_obj_per_s"] > doc["first_obj_per_s"]


@pytest.mark.slow
@pytest.mark.blender
def test_ingest_captures_bench() -> None:
    """Issue 56: the cost at the paper's scale, per step (ingest, canonical render, filter), with each step's
    peak memory per worker and the extrapolation to 2,000 objects."""
    doc = run_smoke("ingest", None, args=("--captures", "2"))[-1]
    assert doc["bench"] == "ingest_captures" and doc["objects"] == 2 and doc["faces"] > 10_000
    check_figures(doc, [f"steps.{s}.{k}" for s in ("ingest", "render", "filter")
                        for k in ("s_per_object", "peak_rss_mb_per_worker", "wall_s")]
                  + ["extrapolated_2000.worker_hours", "extrapolated_2000.hours_at_workers"])
    assert doc["steps"]["ingest"]["detail"]["new"] == 2 and doc["steps"]["render"]["detail"]["rendered"] == 2
    by_step = doc["extrapolated_2000"]["by_step_hours"]
    assert doc["extrapolated_2000"]["hours_at_workers"] == pytest.approx(sum(by_step.values()), abs=0.05)


@pytest.mark.slow
def test_curation_copies_bench() -> None:
    """Issue 57's copy pool, one original (pybullet's duck) with its six copies and a look-alike: each copy paired."""
    doc = run_smoke("curation_copies", None)[-1]
    if "tuning" not in doc:
        pytest.skip("bench/curation_copies.py --smoke skipped its part: a public package cannot be had")
    check_figures(doc, ["tuning.objects", "tuning.candidate_pairs", "tuning.precision", "tuning.seconds"]
                  + [f"tuning.per_kind.tuning.{k}.paired" for k in ("print", "resolution", "squash", "units", "pose", "reindex")])
    assert doc["tuning"]["missed"] == [] and doc["tuning"]["false_pairs"] == []


def test_review_import_bench() -> None:
    doc = run_smoke("review_import", None)[-1]
    check_figures(doc, ["sizes.0.n", "sizes.0.import_s", "sizes.0.again_s", "sizes.0.per_entry_ms", "sizes.0.recorded"])
    assert doc["sizes"][0]["recorded"] > 0 and doc["sizes"][0]["status_changes"] > 0


@pytest.mark.blender
def test_soak_bench(bench_root: Path) -> None:
    """Faults injected at random (issue 51): whatever they hit, no scene is lost or doubled and every
    failure is explained."""
    doc = run_smoke("soak", bench_root)[-1]
    assert doc["bench"] == "soak" and doc["scenes_finished"] == doc["n"] == 2
    check_figures(doc, ["wall_s", "scenes_lost", "duplicates", "failures_explained_pct", "disk_per_scene_kb"])
    assert doc["scenes_lost"] == 0 and doc["duplicates"] == 0 and doc["verify_ok"]
    assert doc["failures_explained_pct"] == 100.0 and doc["failures"] == doc["explained"]


@pytest.mark.slow
@pytest.mark.blender
def test_captions_bench(tmp_path: Path) -> None:
    doc = run_smoke("captions", tmp_path)[-1]
    check_figures(doc, ["active", "mesh_facts", "absolute_sizes", "name_colour_share", "compound_share",
                        "noun_share", "excluded_by_collision", "textured", "textured_agree"])
    assert doc["mesh_facts"] == doc["absolute_sizes"] == doc["excluded_by_collision"] == 0
    assert doc["textured"] >= 3 and doc["textured_agree"] == doc["textured"]


@pytest.mark.slow
@pytest.mark.blender
def test_real_size_physics_bench(tmp_path: Path) -> None:
    """Issue 70: one real-size scene of 2 mm parts settles with nothing lost, at the scale the rule chose."""
    doc = run_smoke("real_size_physics", None, args=("--work", str(tmp_path)))[-1]
    (row,) = doc["summary"]
    check_figures(row, ["spawned", "lost", "kept", "worst_overlap", "worst_floor_sink"])
    assert row["band"] == "2 mm" and row["scenes"] == 1 and row["errors"] == 0 and row["lost"] == 0
    assert row["scales"][0] * 0.0012 >= 0.45  # the smallest part at the paper's smallest scene size


@pytest.mark.ray
def test_ray_catalog_bench(tmp_path: Path) -> None:
    """bench/ray_catalog.py --smoke: a 1-object demo library ingested locally and on a two-node Ray cluster
    (its own, killed at the end) gives the same catalog; the figures are there."""
    doc = run_smoke("ray_catalog", None, args=("--work", str(tmp_path / "rc")))[-1]
    check_figures(doc, ["runs.local.total_s", "runs.ray.total_s", "runs.ray.objects_differing", "runs.ray.objects"])
    ray = doc["runs"]["ray"]
    assert ray["same_catalog"] is True and ray["objects"] == doc["runs"]["local"]["objects"] > 0
    assert ray["exit"] == {"ingest": 0}


def test_materials_kept_bench() -> None:
    """Issue 70 item 1: two coloured KiCad STEP parts keep more than one look each in their converted assets
    (the old conversion kept one per part: looks in assets == files)."""
    doc = run_smoke("materials_kept", None)[-1]
    if "skipped" in doc:
        pytest.skip(doc["skipped"])
    step = doc["STEP"]
    check_figures(step, ["files", "kept_all", "looks_in_files", "looks_in_assets"])
    assert step["files"] == 2 and step["looks_in_assets"] > step["files"]
    assert step["looks_in_assets"] >= 0.8 * step["looks_in_files"]


@pytest.mark.blender
def test_cad_colours_bench() -> None:
    """Issue 70 items 1 and 6: a coloured KiCad LED through ingest, render and caption: several colours in
    its render, and the unit shown is the file's own (mm)."""
    doc = run_smoke("cad_colours", None)[-1]
    if "skipped" in doc:
        pytest.skip(doc["skipped"])
    (row,) = doc["rows"]
    assert row["file_colours"] >= 2 and row["render_colours"] >= 2 and row["unit"].startswith("mm")


def test_every_bench_has_a_smoke_mode_and_a_test_here() -> None:
    """A bench added to bench/ without ``--smoke`` or without its test above fails here (bench/pools.py is
    the benches' shared helper and bench/count_sheet.py, which draws docs/count_targets_look.png from
    bench/counts.py's scene folders, are not benches)."""
    not_benches = {"pools", "count_sheet", "big_meshes"}  # shared helpers (big_meshes: bench/ingest.py's objects); a picture
    benches = sorted(p.stem for p in BENCH.glob("*.py") if p.stem not in not_benches)
    tested = {name[len("test_"):-len("_bench")] for name in globals() if name.startswith("test_") and name.endswith("_bench")}
    assert [b for b in benches if '"--smoke"' not in (BENCH / f"{b}.py").read_text()] == []
    assert [b for b in benches if b not in tested] == []


def test_house_bench() -> None:
    """The house's static figures (issue 58): every list and count is there and agrees with itself, and the
    rules tests/test_code_shape.py asserts read the same here (no file over the limit is missing its entry)."""
    (figures,) = run_smoke("house", None)
    assert figures["private_import_count"] == len(figures["private_imports"])
    assert all(" -> " in line for line in figures["private_imports"])
    assert all(len(group) > 1 for group in figures["import_circles"])
    assert all(lines > 520 for lines in figures["files_over_520"].values())
    longest = list(figures["longest_files"].values())
    assert longest == sorted(longest, reverse=True) and len(longest) == 5
    assert figures["performance_md_lines"] > 0 and "config_path" not in figures


@pytest.mark.blender
def test_render_cost_bench() -> None:
    """Issue 69 item 1: where a canonical render's CPU goes (sync/BVH, path tracing, each prefilter)."""
    doc = run_smoke("render_cost", None)[-1]
    assert doc["bench"] == "render_cost" and doc["faces"] > 10_000
    cpu = doc["cpu_s"]
    check_figures(doc, ["per_sample_cpu_s", "cpu_s.import", "cpu_s.sync_bvh_16px_1spp", "cpu_s.64px_4spp"])
    assert set(cpu) == {"import", "sync_bvh_16px_1spp", "64px_1spp", "64px_4spp", "64px_4spp_denoise_FAST",
                        "64px_4spp_denoise_ACCURATE"}
    assert all(v >= 0 for v in cpu.values())
