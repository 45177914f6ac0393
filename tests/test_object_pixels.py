"""Compose says when objects are too small to count (issue 70): pixels per counted object (the longer side
of its box) from the plan at the start of a run and from the written images in its summary, against
``compose.min_object_px``. One real quick-config compose at 48 px, where the demo objects come out a few
pixels wide, and its dry run with the floor lowered."""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any, Callable

import pytest

from mixcount.run.object_pixels import PixelTally, measured_object_px, summary_lines

pytestmark = [pytest.mark.blender, pytest.mark.slow]


def test_tally_median_and_smallest_match_the_plain_figures() -> None:
    values = [3.0, 7.0, 7.0, 12.0, 40.0, 9.0]
    tally = PixelTally.empty()
    tally.add(values[:4])
    tally.add(values[4:])
    assert tally.median() == statistics.median(values) and tally.smallest() == 3.0
    assert (tally.objects, tally.scenes) == (6, 2)
    sizes = tally.sizes(10.0, "images")
    assert sizes.under_floor and "UNDER the floor compose.min_object_px = 10 px" in sizes.line()
    assert not tally.sizes(8.0, "images").under_floor and not tally.sizes(0.0, "images").under_floor
    assert PixelTally.empty().median() is None and not PixelTally.empty().sizes(10.0, "plan").under_floor


def _cli(capsys: Any, *args: str) -> tuple[int, str, str]:
    """``mixcount ARGS`` in this process: (exit code, stdout, stderr)."""
    from mixcount.cli import main

    capsys.readouterr()
    code = main(list(args))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_small_objects_are_said_at_the_start_and_in_the_summary(tmp_path: Path, capsys: Any,
                                                               demo_catalog_copy: Callable[[Path, int], Path]) -> None:
    root = demo_catalog_copy(tmp_path / "cat", 12)
    base = ["--db", str(root / "catalog.db"), "--config", "quick"]
    out = tmp_path / "out"
    code, stdout, err = _cli(capsys, *base, "compose", "--n", "1", "--seed", "3", "--resolution", "48", "--out",
                             str(out), "--json")
    assert code == 0, err[-3000:]
    assert "objects are too small to count" in err and "compose.min_object_px = 32 px" in err
    summary = json.loads(stdout)
    px = summary["object_px"]
    images, plan = px["images"], px["plan"]
    assert px["floor_px"] == 32.0 and images["under_floor"] and plan["under_floor"]
    (scene,) = sorted(p for p in (out / "scenes").iterdir() if not p.name.startswith("."))
    sides = measured_object_px(scene)  # the visible counted objects of coco.json, distractors left out
    coco = json.loads((scene / "coco.json").read_text())
    assert len(sides) == sum(1 for a in coco["annotations"] if not a["is_distractor"]) == images["objects"] > 0
    assert images["median_px"] == statistics.median(round(s) for s in sides) < 32
    assert images["smallest_px"] == min(round(s) for s in sides)
    assert 0.5 < plan["median_px"] / images["median_px"] < 2.0  # the plan foretells what the images show
    (line,) = summary_lines(px)  # the text summary's line: the images' figures
    assert f"median {images['median_px']:g} px, smallest {images['smallest_px']:g} px" in line and "UNDER" in line

    # the text summary says it too; a dry run with the floor lowered to 4 px warns of nothing
    code, _out, err = _cli(capsys, *base, "--set", "compose.min_object_px=4", "compose", "--n", "2", "--seed", "3",
                           "--resolution", "48", "--out", str(tmp_path / "dry"), "--dry-run")
    assert code == 0, err[-2000:]
    assert "too small to count" not in err and "at or above the floor compose.min_object_px = 4 px" in err
