"""The bpy worker's imports never depend on the caller's folder (issue 70): ``python -m`` alone puts the
current folder first on ``sys.path``, so a shell standing in a folder that holds a directory named
``mixcount`` (the folder a user cloned into) made every canonical render fail with ``ModuleNotFoundError``
while the command exited 0. Real bpy, one 32 px render, run by the installed ``mixcount`` command from
such a folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mixcount.worker.client import package_root, worker_command

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def _shadowing_folder(root: Path) -> Path:
    """A folder holding a package named ``mixcount`` that is not mixcount (as a clone's parent folder
    holds the source tree), whose import says so."""
    fake = root / "mixcount"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("SHADOW = True\n")
    (fake / "engine").mkdir()
    (fake / "engine" / "__init__.py").write_text("")
    return root


def test_worker_command_keeps_the_current_folder_off_the_path(tmp_path: Path) -> None:
    args, env = worker_command(sys.executable, "mixcount.engine.worker_main", {"PYTHONPATH": "/elsewhere"})
    assert args[1:] == ["-P", "-m", "mixcount.engine.worker_main"]
    assert env["PYTHONPATH"].split(os.pathsep) == [package_root(), "/elsewhere"]
    folder = _shadowing_folder(tmp_path / "shell")
    probe = "import mixcount, sys; print(mixcount.__file__); print('' in sys.path or '.' in sys.path)"
    for start, expect_shadow in (([sys.executable, "-c", probe], True), ([*args[:2], "-c", probe], False)):
        proc = subprocess.run(start, cwd=folder, env=env if not expect_shadow else {**env, "PYTHONPATH": ""},
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        where, cwd_on_path = proc.stdout.split()
        assert (where == str(folder / "mixcount" / "__init__.py")) is expect_shadow, where
        assert cwd_on_path == str(expect_shadow)  # the bare start shows the trap; -P shuts it


def test_catalog_render_from_a_folder_holding_a_mixcount_package(tmp_path: Path) -> None:
    lib = tmp_path / "lib"
    lib.mkdir()
    box = trimesh.creation.box(extents=(0.05, 0.03, 0.02))
    box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=np.tile([220, 30, 30, 255], (len(box.vertices), 1)))
    box.export(lib / "redbox.glb")
    shell = _shadowing_folder(tmp_path / "clone")
    command = Path(sys.executable).with_name("mixcount")
    base = [str(command), "--db", str(tmp_path / "catalog.db"), "--config", "quick",
            "--set", "canonical_render.resolution=32", "--set", "canonical_render.samples=1"]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    ingest = subprocess.run([*base, "catalog", "ingest", str(lib)], cwd=shell, env=env, capture_output=True,
                            text=True, timeout=300)
    assert ingest.returncode == 0, ingest.stderr[-2000:]
    render = subprocess.run([*base, "catalog", "render", "--json"], cwd=shell, env=env, capture_output=True,
                            text=True, timeout=600)
    assert render.returncode == 0, render.stderr[-3000:]
    assert "ModuleNotFoundError" not in render.stdout + render.stderr
    import json

    report = json.loads(render.stdout)
    assert report["rendered"] == 1 and report["failed"] == 0, report
    assert len(list((tmp_path / "renders").rglob("*.png"))) >= 1


@pytest.mark.ray
def test_ray_workers_started_from_such_a_folder_import_mixcount_itself(tmp_path: Path) -> None:
    """Ray puts the driver's current folder first on its workers' ``sys.path`` at ``ray.init``: the executor
    starts Ray from the package's folder (:func:`mixcount.worker.client.in_package_root`)."""
    pytest.importorskip("ray")
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import os, ray\n"
        "from mixcount.worker.client import in_package_root\n"
        "kw = dict(num_cpus=1, include_dashboard=False, _node_ip_address='127.0.0.1', log_to_driver=False)\n"
        "with in_package_root():\n"
        "    ray.init(**kw)\n"
        "print(os.getcwd())\n"
        "@ray.remote\n"
        "def where():\n"
        "    import mixcount\n"
        "    return mixcount.__file__\n"
        "print(ray.get(where.remote()))\n"
        "ray.shutdown()\n")
    shell = _shadowing_folder(tmp_path / "clone")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, str(probe)], cwd=shell, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    cwd, where = proc.stdout.split()[-2:]
    assert cwd == str(shell)  # the driver's own folder is back after ray.init
    # without the wrap the remote task imported <shell>/mixcount/__init__.py (ray 2.x, docs/faults.md)
    assert where == str(Path(package_root()) / "mixcount" / "__init__.py")
