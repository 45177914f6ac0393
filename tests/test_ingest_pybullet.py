"""Real folders as they come, on pybullet's own ``pybullet_data`` (issue 52): ``bench/ingest.py --pybullet``
copies 20 of its models into person-named folders with what ships beside them and ingests them twice.
Skips, with the bench's reason, where no pybullet_data or pybullet wheel can be found offline."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_pybullet_data_in_person_named_folders() -> None:
    done = subprocess.run([sys.executable, str(ROOT / "bench" / "ingest.py"), "--pybullet", "--workers", "1"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    if "skipped" in doc:
        pytest.skip(doc["skipped"])
    rows = {r["name"]: r for r in doc["objects_detail"]}
    assert (doc["objects"], doc["broken"]) == (20, 0), [(r["name"], r["error"]) for r in rows.values() if r["error"]]
    assert doc["named_by_folder"] == 20 and doc["companions_as_objects"] == 0
    assert rows["red_mug"]["category"] == rows["blue_mug"]["category"] == "mug"
    assert rows["Rubber duck"]["collision_companion"] and rows["red_mug"]["collision_companion"]
    # the package's own gaps are tolerated and flagged: cube.obj's missing cube.mtl, jenga's jenga.tga
    assert "missing_material" in rows["Sugar cube"]["flags"] and "missing_texture" in rows["Jenga block"]["flags"]
    # Z-up by the URDF beside them: the tray lies flat, the mug stands (height 0.1 m along Z)
    assert rows["Serving tray"]["up_axis"] == "Z" and "URDF" in rows["Serving tray"]["up_axis_reason"]
    tray = rows["Serving tray"]["dims_m"]
    assert tray[2] < 0.3 * min(tray[:2])
    assert rows["red_mug"]["up_axis"] == "Z" and rows["red_mug"]["dims_m"][2] == pytest.approx(0.1, abs=0.002)
    assert rows["Rubber duck"]["units"] == "0.05"  # the URDF's scale
    assert doc["second"] == {"new": 0, "updated": 0, "unchanged": 20, "broken": 0, "reoriented": 0}
