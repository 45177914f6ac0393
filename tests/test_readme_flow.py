"""The README's commands, as a user runs them (issue 35, item 6).

* ``make demo``'s table shows the commands ``make demo`` runs (the Makefile is the source).
* "Using it on your own objects": every command of that block is read out of README.md and run as written,
  by the console entry point, from a working folder outside the repository (no ``--db``: the catalog is
  ``./catalog/catalog.db`` of that folder), on a small generated library shaped like real ones: a DTC
  folder, a Google Scanned Objects folder and loose files a person named (with an FBX and a COLLADA file
  beside them), plus HDR/EXR maps and a PBR texture set. What the test changes, and nothing else:

  - ``/data/<name>`` paths -> the generated folders;
  - ``--config quick`` and tiny render sizes put after ``mixcount`` (what the README's "Try it small
    first" says); ``--n`` -> 1 and ``--workers`` -> 1 (two CPUs);
  - ``decisions.json`` is written by the test, as the person using review.html would export it.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
SMALL = ["--config", "quick", "--set", "canonical_render.resolution=64", "--set", "canonical_render.samples=2",
         "--set", "compose.resolution=64", "--set", "compose.samples=2"]


def readme_block(heading: str) -> list[str]:
    """The commands of the first code block under ``heading``: comments dropped, ``&&`` split."""
    text = README.read_text(encoding="utf-8")
    section = text.split(f"## {heading}", 1)[1]
    block = section.split("```", 2)[1]
    commands: list[str] = []
    for line in block.splitlines():
        line = line.split("#", 1)[0].strip()
        commands.extend(part.strip() for part in line.split("&&") if part.strip())
    return commands


def demo_table_commands() -> list[str]:
    """Every ``mixcount ...`` command the README's make-demo table shows."""
    text = README.read_text(encoding="utf-8").split("## What `make demo` does", 1)[1].split("\n## ", 1)[0]
    return [c for c in re.findall(r"`(mixcount [^`]+)`", text)]


def makefile_demo_commands() -> list[str]:
    """The mixcount commands of ``make demo``, with the Makefile's variables filled in."""
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    values = dict(re.findall(r"^(\w+) \??:?= ?(.*)$", text, flags=re.M))
    recipe = text.split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    commands = []
    for line in recipe.splitlines():
        line = line.strip()
        line = line.replace("$(MIX)", "mixcount --db $(DEMO_DB)").replace("$(VENV)/bin/mixcount", "mixcount")
        for _ in range(3):
            line = re.sub(r"\$\((\w+)\)", lambda m: values.get(m.group(1), m.group(0)), line)
        if line.startswith("mixcount"):
            commands.append(line.replace(f" --db {values['DEMO_DB']}", ""))
    return commands


def test_make_demo_table_shows_what_make_demo_runs():
    shown = demo_table_commands()
    run = makefile_demo_commands()
    assert len(shown) >= 10 and len(run) >= 12
    assert [c for c in shown if c not in run] == []
    compose = next(c for c in shown if " compose " in c)
    assert "--split train" in compose and "--config quick" in compose


# ------------------------------------------------------------------------------------ the library


def _loose_files(root: Path) -> None:
    root.mkdir(parents=True)
    trimesh.creation.box(extents=(0.06, 0.04, 0.04)).export(root / "red_block.glb")
    trimesh.creation.icosphere(subdivisions=2, radius=0.05).export(root / "big ball.stl")
    trimesh.creation.cylinder(radius=0.04, height=0.1).export(root / "coffee-mug-02.ply")
    trimesh.creation.capsule(radius=0.015, height=0.1).export(root / "blue marker.obj")
    (root / "chair.fbx").write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00")
    (root / "lamp.dae").write_text('<?xml version="1.0"?><COLLADA version="1.4.1"/>')


def _environments(root: Path) -> None:
    from test_scene_environments import write_exr, write_hdr

    write_hdr(root / "studio.hdr")
    write_exr(root / "sunset.exr")


def _materials(root: Path) -> None:
    mats = root / "Planks_01"
    mats.mkdir(parents=True)
    for name, colour in (("Planks_01_Color.png", (140, 100, 60)), ("Planks_01_Roughness.png", (190, 190, 190)),
                         ("Planks_01_NormalGL.png", (128, 128, 255))):
        Image.new("RGB", (16, 16), colour).save(mats / name)


def make_library(data: Path) -> dict[str, Path]:
    """The folders the README's ``/data/<name>`` paths stand for."""
    from test_layouts import gso_tree

    from mixcount.demo.library import generate_demo_library

    generate_demo_library(data / "dtc", seed=0, n_objects=10)
    gso_tree(data / "gso")
    _loose_files(data / "more_models")
    _environments(data / "hdris")
    _materials(data / "pbr")
    return {name: data / name for name in ("dtc", "gso", "more_models", "hdris", "pbr")}


def as_run(command: str, folders: dict[str, Path]) -> list[str]:
    """The README command as the test runs it (see the module docstring for every change)."""
    words = shlex.split(command)
    assert words[0] == "mixcount", command
    args: list[str] = []
    for k, word in enumerate(words[1:], start=1):
        if word.startswith("/data/"):
            word = str(folders[word.removeprefix("/data/").strip("/")])
        elif words[k - 1] in ("--n", "--workers"):
            word = "1"
        args.append(word)
    return [*SMALL, *args]


def decisions_for(work: Path, env: dict[str, str]) -> None:
    """What the person exports from review/review.html: accept the first flagged object."""
    listed = subprocess.run([sys.executable, "-m", "mixcount", "catalog", "list", "--json"], cwd=work, env=env,
                            capture_output=True, text=True, timeout=120, check=True)
    flagged = [o for o in json.loads(listed.stdout) if o["flags"] and o["status"] != "broken"]
    chosen = flagged[:1]
    (work / "decisions.json").write_text(json.dumps({
        "format": "mixcount-review-v1", "reviewer": "readme-test", "exported_at": "2026-01-01T00:00:00.000Z",
        "decisions": [{"id": o["id"], "name": o["name"], "decision": "accept", "note": "checked by eye",
                       "decided_at": "2026-01-01T00:00:00.000Z"} for o in chosen]}))


@pytest.mark.blender
@pytest.mark.slow
def test_readme_own_objects_flow_runs_as_written_from_another_folder(tmp_path):
    commands = readme_block("Using it on your own objects")
    assert any(c.startswith("mixcount compose") for c in commands) and commands[0].startswith("mixcount catalog ingest")
    folders = make_library(tmp_path / "data")
    work = tmp_path / "work"
    work.mkdir()
    assert ROOT not in work.parents and work != ROOT
    env = {k: v for k, v in os.environ.items() if k != "MIXCOUNT_DB"}
    printed: dict[str, str] = {}
    for command in commands:
        if " review import " in command:
            decisions_for(work, env)
        args = as_run(command, folders)
        res = subprocess.run([sys.executable, "-m", "mixcount", *args], cwd=work, env=env, capture_output=True,
                             text=True, timeout=900)
        assert res.returncode == 0, (command, res.stderr[-3000:])
        assert "Traceback" not in res.stderr, command
        assert "{'" not in res.stdout and "None" not in res.stdout, (command, res.stdout[-2000:])
        printed[command] = res.stdout + res.stderr
    # what is on disk after: one catalog in the working folder, one dataset of two splits, the export
    assert (work / "catalog" / "catalog.db").is_file()
    ingest = next(v for k, v in printed.items() if k.startswith("mixcount catalog ingest "))
    assert "skipped 2 file(s)" in ingest and "chair.fbx" in ingest and "lamp.dae" in ingest
    dataset = work / "dataset"
    for split in ("train", "test"):
        doc = json.loads((dataset / "annotations" / f"instances_{split}.json").read_text())
        assert len(doc["images"]) == 1 and doc["annotations"], split
    predictions = json.loads((work / "predictions.json").read_text())
    assert predictions["reference"].endswith("instances_train.json")
    evaluated = next(v for k, v in printed.items() if k.startswith("mixcount evaluate"))
    assert "MAE" in evaluated and "instances_test.json" in evaluated
    assert (work / "exports" / "fsc147").is_dir() and any((work / "exports" / "fsc147").rglob("*.json"))
    assert (work / "review" / "review.html").is_file()
