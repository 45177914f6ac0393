"""Progress where stderr is not a terminal (issue 52): plain lines at the first step, at most every
interval (a clock given by the test, no timing), and at the end; the CLI's reporter uses them when its
console is not a terminal (``catalog render`` into a log file showed nothing for minutes)."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from mixcount.commands.common import RichProgress
from mixcount.progress import PlainProgress
from tests.package_folders import build_package_folders

ROOT = Path(__file__).resolve().parent.parent


def test_plain_lines_first_periodic_and_last():
    now = [100.0]
    out = io.StringIO()
    bar = PlainProgress(out, interval_s=10.0, clock=lambda: now[0])
    bar.start("render", 5)
    for step in range(5):
        now[0] += 4.0  # 4 s a step: lines at steps 1 and 4 (12 s after the first), then the end
        bar.advance(info=f"obj {step}")
    bar.note("one failed")
    bar.stop()
    lines = out.getvalue().splitlines()
    assert lines[0] == "render: 1/5 (20 %), elapsed 0:00:04, ETA 0:00:16 obj 0"
    assert lines[1].startswith("render: 4/5 (80 %), elapsed 0:00:16, ETA 0:00:04")
    assert lines[2] == "one failed"
    assert lines[3] == "render: 5/5 (100 %), elapsed 0:00:20 obj 4"
    assert len(lines) == 4


def test_cli_reporter_prints_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    bar = RichProgress(Console(file=out, force_terminal=False))
    bar.start("ingest", 2)
    bar.advance()
    bar.advance()
    bar.stop()
    text = out.getvalue()
    assert "ingest: 1/2 (50 %)" in text and "ingest: 2/2 (100 %)" in text


@pytest.mark.blender
@pytest.mark.slow
def test_catalog_render_into_a_pipe_shows_progress(tmp_path):
    """The issue's case: ``catalog render`` with stderr not a terminal (here a pipe) prints progress lines.
    The object is the Jenga block whose texture is missing: it renders in its material's colour (tan), not
    in the magenta Blender paints a missing image with."""
    lib = build_package_folders(tmp_path / "lib")
    db = str(tmp_path / "c.db")
    env = {**os.environ, "COLUMNS": "400"}
    run = [sys.executable, "-m", "mixcount", "--db", db]
    done = subprocess.run([*run, "catalog", "ingest", str(lib / "Jenga block")], capture_output=True, text=True,
                          timeout=300, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    done = subprocess.run([*run, "--set", "canonical_render.resolution=32", "--set", "canonical_render.samples=1",
                           "catalog", "render"], capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "render: 1/1 (100 %)" in done.stderr, done.stderr
    import numpy as np
    from PIL import Image

    rgb = np.asarray(Image.open(tmp_path / "renders" / "c" / "obj_000001.png").convert("RGB"), dtype=float)
    body = rgb[(rgb < 245).any(axis=2)]  # the object's pixels (the background is white)
    assert len(body) > 50
    red, green, _blue = body.mean(axis=0)
    assert green > 0.5 * red, (red, green)  # tan (Kd 0.9 0.7 0.5), not magenta (1 0 1)
