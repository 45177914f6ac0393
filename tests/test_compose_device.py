"""``compose --device cpu|gpu|auto`` (``[compose] device``, mixcount.run.devices, mixcount.engine.devices).

Real bpy: the device probe runs in a bpy worker subprocess. These tests are written for (and were run on)
a machine without a usable GPU: ``--device gpu`` must stop with one line and exit 2 before OUT exists,
``--device auto`` must render on the CPU and say so once, and each scene records its device (the default
``cpu`` is recorded too: tests/test_blender_worker.py::test_compose_passes_choose_the_written_files). On a machine
where Cycles finds a GPU the no-GPU test skips (it says why). The Ray side's choice (cluster GPU resources,
``num_gpus`` per actor) is checked on its pure function.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import pytest

from mixcount.cli import main

BASE = ["--config", "quick", "--set", "scene.n_objects=[6,10]"]


def _compose(root: Path, out: Path, *args: str) -> int:
    return main(["--db", str(root / "catalog.db"), *BASE, "compose", "--split", "train", "--seed", "3",
                 "--samples", "1", "--resolution", "48", "--out", str(out), *args])


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


@pytest.mark.blender
def test_device_gpu_without_a_gpu_exits_2_with_one_line_and_writes_nothing(
        tmp_path: Path, demo_catalog_copy: Callable[[Path, int], Path], capsys: pytest.CaptureFixture[str]) -> None:
    from mixcount.run.devices import probe_in_worker

    found = probe_in_worker("auto")
    if found.used == "GPU":
        pytest.skip(f"this machine has a usable GPU ({found.backend}: {', '.join(found.devices)}): the no-GPU "
                    "path cannot be seen here")
    root = demo_catalog_copy(tmp_path / "cat", 8)
    out = tmp_path / "out"
    capsys.readouterr()
    assert _compose(root, out, "--n", "1", "--device", "gpu") == 2
    captured = capsys.readouterr()
    lines = _lines(captured.out) + _lines(captured.err)
    assert len(lines) == 1, lines
    assert 'compose.device = "gpu" but Cycles found no usable GPU' in lines[0] and "nothing was written" in lines[0]
    assert "OPTIX, CUDA" in lines[0]  # the backends tried are named
    assert not out.exists()


@pytest.mark.blender
def test_device_auto_renders_on_the_cpu_said_once_and_each_scene_records_it(
        tmp_path: Path, demo_catalog_copy: Callable[[Path, int], Path], capsys: pytest.CaptureFixture[str]) -> None:
    from mixcount.run.devices import probe_in_worker

    if probe_in_worker("auto").used == "GPU":
        pytest.skip("this machine has a usable GPU: auto renders on it, not on the CPU")
    root = demo_catalog_copy(tmp_path / "cat", 8)
    out = tmp_path / "out"
    capsys.readouterr()
    assert _compose(root, out, "--n", "2", "--device", "auto", "--json") == 0
    captured = capsys.readouterr()
    said = [ln for ln in (captured.out + captured.err).splitlines() if "rendering on the CPU" in ln]
    summary = json.loads(captured.out)
    assert summary["device"] == "cpu"
    assert [w for w in summary["warnings"] if "rendering on the CPU" in w] == [
        'compose.device = "auto": no usable GPU (Cycles found ' + [w for w in summary["warnings"] if "rendering on the CPU" in w][0].split("found ", 1)[1]]
    assert len([ln for ln in said if not ln.startswith("{")]) == 1  # the note, once (besides the JSON summary)
    scenes = sorted((out / "scenes").glob("scene_*"))
    assert len(scenes) == 2
    for d in scenes:
        meta = json.loads((d / "metadata.json").read_text())
        assert meta["render_device"]["used"] == "CPU" and meta["render_device"]["backend"] == "NONE"


def test_a_bad_device_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["--db", str(tmp_path / "catalog.db"), "compose", "--device", "tpu", "--out", str(tmp_path / "o")]) == 2
    captured = capsys.readouterr()
    lines = _lines(captured.out) + _lines(captured.err)
    assert len(lines) == 1 and "compose.device must be one of cpu, gpu, auto, got 'tpu'" in lines[0], lines
    assert not (tmp_path / "o").exists()


def test_resolve_device_probes_only_off_the_cpu_and_says_why_once() -> None:
    """The decision on the probe's answer (the real probe runs in the bpy tests above)."""
    from mixcount.errors import RenderError
    from mixcount.run.devices import resolve_device
    from mixcount.worker.rerender_contract import DevicesResult

    asked: list[str] = []

    def none(device: str) -> DevicesResult:
        asked.append(device)
        if device == "gpu":
            return DevicesResult(used="", backend="", devices=(), found=("CPU: x",), error='compose.device = "gpu" but ...')
        return DevicesResult(used="CPU", backend="NONE", devices=(), found=("CPU: x",), error="")

    def one(device: str) -> DevicesResult:
        return DevicesResult(used="GPU", backend="OPTIX", devices=("OPTIX: H200",), found=("OPTIX: H200",), error="")

    cpu = resolve_device("cpu", none)
    assert (cpu.device, cpu.note, asked) == ("cpu", None, [])
    with pytest.raises(RenderError, match="nothing was written"):
        resolve_device("gpu", none)
    auto = resolve_device("auto", none)
    assert auto.device == "cpu" and auto.note is not None and "rendering on the CPU" in auto.note and "CPU: x" in auto.note
    gpu = resolve_device("auto", one)
    assert gpu.device == "gpu" and gpu.note == "rendering on the GPU: OPTIX OPTIX: H200"


def test_ray_cluster_device_asks_for_gpus_only_where_the_cluster_has_them() -> None:
    from mixcount.errors import ExecutorError
    from mixcount.run.ray_executor import cluster_device

    assert cluster_device("cpu", 8.0, 1.0).device == "cpu"
    assert cluster_device(None, 8.0, 1.0).note is None
    with pytest.raises(ExecutorError, match="has 0 GPU"):
        cluster_device("gpu", 0.0, 1.0)
    auto = cluster_device("auto", 0.0, 1.0)
    assert auto.device == "cpu" and auto.note is not None and "rendering on the CPU" in auto.note
    shared = cluster_device("gpu", 2.0, 0.5)
    assert shared.device == "gpu" and shared.note is not None and "0.5 per scene actor" in shared.note
