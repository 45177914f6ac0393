"""Exit codes that tell the truth (issue 68, item 4; issue 70, item 5): a catalog step over many objects exits
3 when any of them failed, also when every one did, prints one line per failed object (no worker traceback:
those go to the log file) and the command that reruns only those; 0 stays for full success.

Real everything: a four-object library ingested through the CLI, two model files damaged after the ingest
(one deleted, one overwritten with garbage), real bpy canonical renders (32 px, 1 sample)."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest
import trimesh
from sqlalchemy import select

from mixcount.catalog.models import CatalogObject
from mixcount.cli import main
from mixcount.errors import EXIT_PARTIAL, PartialFailure

pytestmark = [pytest.mark.blender, pytest.mark.slow]

SMALL = ["--set", "canonical_render.resolution=32", "--set", "canonical_render.samples=1"]


def _library(root: Path) -> Path:
    root.mkdir(parents=True)
    shapes = {"redbox": trimesh.creation.box(extents=(0.05, 0.03, 0.02)),
              "blueball": trimesh.creation.icosphere(subdivisions=2, radius=0.03),
              "greencan": trimesh.creation.cylinder(radius=0.02, height=0.08),
              "yellowcone": trimesh.creation.cone(radius=0.03, height=0.06)}
    for k, (name, mesh) in enumerate(shapes.items()):
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([40 + 60 * k, 90, 200, 255],
                                                                              (len(mesh.vertices), 1)))
        mesh.export(root / f"{name}.glb")
    return root


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _rerun_line(err: str) -> list[str]:
    line = next(ln for ln in err.splitlines() if ln.startswith("rerun only those: "))
    words = shlex.split(line.removeprefix("rerun only those: "))
    assert words[0] == "mixcount"
    return words[1:]


def test_catalog_steps_with_failed_objects_exit_3_and_rerun_only_those(tmp_path, capsys) -> None:
    lib = _library(tmp_path / "lib")
    db = str(tmp_path / "cat" / "catalog.db")
    code, _, err = _cli(capsys, "--db", db, "catalog", "ingest", str(lib))
    assert code == 0, err
    from mixcount.catalog.db import open_catalog

    cat = open_catalog(db, data_dir="")
    with cat.session() as s:
        objs = {o.name: o for o in s.scalars(select(CatalogObject))}
    cat.close()
    assert len(objs) == 4
    gone = next(o for n, o in objs.items() if "greencan" in n)
    garbage = next(o for n, o in objs.items() if "yellowcone" in n)
    kept_bytes = Path(garbage.model_path).read_bytes()
    Path(gone.model_path).unlink()  # ingested fine, gone by render time
    Path(garbage.model_path).write_bytes(b"glTF" + b"\x00garbage" * 50)  # replaced by garbage

    code, out, err = _cli(capsys, "--db", db, *SMALL, "catalog", "render")
    with capsys.disabled():
        print(f"catalog render, 2 of 4 damaged: exit {code}\n{out}{err}")
    assert code == EXIT_PARTIAL == 3
    assert "render: 4 objects, 2 rendered, 0 up to date, 2 failed" in out
    failed_lines = [ln for ln in err.splitlines() if ln.startswith("failed: ")]
    assert sorted(failed_lines[k].split()[1] for k in range(2)) == sorted([f"#{gone.id}", f"#{garbage.id}"])
    assert len(failed_lines) == 2 and "Traceback" not in err and 'File "' not in err
    summary = next(ln for ln in err.splitlines() if ln.startswith("error: "))
    assert "canonical renders: 2 of 4 failed (full errors: " in summary
    log = Path(summary.split("(full errors: ", 1)[1].rstrip(")"))
    assert log.is_file() and f"#{gone.id} " in log.read_text() and f"#{garbage.id} " in log.read_text()
    rerun = _rerun_line(err)
    assert rerun[-3:] == ["catalog", "render", "--only-failed"] and rerun[:2] == ["--db", db]

    # the filter cannot describe the vanished model: exit 3 too, one line for it
    code, out, err = _cli(capsys, "--db", db, "catalog", "filter")
    assert code == 3 and "Traceback" not in err
    assert any(ln.startswith(f"failed: #{gone.id} ") for ln in err.splitlines())

    # one file restored: the rerun renders only the two failed ones; the one still missing fails
    Path(garbage.model_path).write_bytes(kept_bytes)
    code, out, err = _cli(capsys, *rerun)
    with capsys.disabled():
        print(f"rerun: exit {code}\n{out}{err}")
    assert code == 3 and "render: 2 objects, 1 rendered, 0 up to date, 1 failed" in out
    assert "canonical renders: every one of 1 failed" not in err and "canonical renders: 1 of 2 failed" in err

    # a step in which every item failed never exits 0
    code, out, err = _cli(capsys, *_rerun_line(err))
    assert code == 3 and "render: 1 objects, 0 rendered, 0 up to date, 1 failed" in out
    assert "canonical renders: every one of 1 failed" in err

    # full success exits 0: the last one excluded from the rerun's reach by its file coming back
    Path(gone.model_path).parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.cylinder(radius=0.02, height=0.08).export(gone.model_path)
    code, out, err = _cli(capsys, "--db", db, *SMALL, "catalog", "render", "--only-failed")
    assert code == 0, err
    code, out, err = _cli(capsys, "--db", db, *SMALL, "catalog", "render", "--only-failed")
    assert code == 0 and "no object has a failed render" in out


def test_partial_failure_prints_one_line_per_item_and_the_rerun(capsys) -> None:
    """The CLI's side alone: many failed items are cut at 50 lines, reasons at one line each."""
    from mixcount.cli import FAILED_LINES, print_partial

    failed = [(f"#{k} obj{k}", f"RenderError: boom {k}\nTraceback (most recent call last):\n  File \"x\"")
              for k in range(FAILED_LINES + 7)]
    print_partial(PartialFailure("things", failed, 100, rerun="mixcount again --only-failed", log="/l/x.log"))
    err = capsys.readouterr().err.splitlines()
    assert len([ln for ln in err if ln.startswith("failed: #")]) == FAILED_LINES
    assert "failed: ... and 7 more (every one in /l/x.log)" in err
    assert "error: things: 57 of 100 failed (full errors: /l/x.log)" in err
    assert err[-1] == "rerun only those: mixcount again --only-failed"
    assert not any("Traceback" in ln for ln in err)


def test_compose_with_failed_seeds_exits_3_with_the_seeds_to_compose_again(tmp_path, monkeypatch, capsys) -> None:
    """compose's side (no render: the run's summary given): two failed seeds made up by others still exit 3,
    one line per failed scene, and the loop that composes each failed seed again with the same options."""
    from mixcount.catalog.db import open_catalog
    from mixcount.run.compose import ComposeSummary
    from mixcount.run.compose_entry import ComposeJob

    db = tmp_path / "catalog.db"
    open_catalog(str(db), data_dir="").close()
    out = tmp_path / "out"
    failures = [{"scene_id": f"scene_{s:06d}", "seed": s, "cause": "worker SIGSEGV",
                 "error": "WorkerDied: worker0: worker died (SIGSEGV, exit code -11) while handling 'scene'; last "
                          "lines:\nFatal Python error: Segmentation fault\n  File \"x.py\", line 3 in render"}
                for s in (7, 9)]
    summary = ComposeSummary(requested=2, written=2, failed=2, failures=failures)
    monkeypatch.setattr(ComposeJob, "run", lambda self, catalog, **kw: summary)
    code, stdout, err = _cli(capsys, "--db", str(db), "compose", "--n", "2", "--seed", "6", "--out", str(out),
                             "--resolution", "64", "--split", "train")
    assert code == 3 and "Traceback" not in err and "Fatal Python error" not in err
    assert "failed: scene_000007 (seed 7): [worker SIGSEGV] WorkerDied: worker0: worker died (SIGSEGV" in err
    assert any(ln.startswith("failed: scene_000009 (seed 9): ") for ln in err.splitlines())
    assert f"error: compose: 2 seed(s) failed (full errors: {out / 'logs' / 'failures.jsonl'})" in err
    rerun = next(ln for ln in err.splitlines() if ln.startswith("rerun only those: "))
    assert rerun == ("rerun only those: for s in 7 9; do mixcount --db " + str(db) + " compose --out " + str(out)
                     + " --split train --resolution 64 --n 1 --seed $s; done")

    summary.failures, summary.failed = [], 0  # the same run without a failed seed: 0
    code, _, err = _cli(capsys, "--db", str(db), "compose", "--n", "2", "--out", str(out))
    assert code == 0, err
