"""`catalog ingest` of a hostile library (tests/hostile_library.py, issue 68 items 1, 7, 8): nothing from
outside the library is recorded, staged or read; every case is said with its path and reason; a link to
``/`` costs nothing; metadata of another meaning is ignored and said once; description bombs are a
warning; the broken objects are reported work, so the command exits 0."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mixcount.catalog.layouts.discovery import discover
from tests.hostile_library import SECRET, build

PROJECT_ROOT = Path(__file__).resolve().parent.parent

# an ingest in a process whose every file open and folder listing is recorded (an audit hook)
AUDITED = """
import json, sys
from pathlib import Path
seen = []
def hook(event, args):
    if event in ("open", "os.scandir", "os.listdir") and args and isinstance(args[0], (str, bytes, Path)):
        seen.append(str(args[0]))
sys.addaudithook(hook)
from mixcount.catalog.db import open_catalog
from mixcount.catalog.ingest import ingest_paths
from mixcount.config import load_config
lib, out = Path(sys.argv[1]), Path(sys.argv[2])
catalog = open_catalog(f"sqlite:///{out / 'audit.db'}", data_dir=str(out / "audit"))
ingest_paths(catalog, [lib], config=load_config([], ["ingest.workers=1"]))
catalog.close()
print(json.dumps(seen))
"""


@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("hostile")
    lib, why = build(tmp)
    if lib is None:
        pytest.skip(why)
    cat = tmp / "cat"
    cat.mkdir()
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    run = subprocess.run([sys.executable, "-m", "mixcount.cli", "--db", str(cat / "c.db"), "catalog", "ingest",
                          str(lib), "--json"], capture_output=True, text=True, env=env, timeout=300, cwd=tmp)
    listed = subprocess.run([sys.executable, "-m", "mixcount.cli", "--db", str(cat / "c.db"), "catalog", "list",
                             "--json"], capture_output=True, text=True, env=env, timeout=120, cwd=tmp)
    return {"tmp": tmp, "lib": lib, "cat": cat, "run": run, "summary": json.loads(run.stdout),
            "objects": json.loads(listed.stdout)}


def test_the_run_says_every_case_and_exits_0(hostile: dict) -> None:
    run, summary, lib = hostile["run"], hostile["summary"], hostile["lib"]
    assert run.returncode == 0, run.stderr[-2000:]
    assert "Traceback" not in run.stderr
    refused = {Path(r["path"]).relative_to(lib).as_posix(): r["reason"] for r in summary["refused"]}
    assert set(refused) == {"rootlink", "outlink", "chain_a", "chain_b", "meta_link/cube/metadata.json",
                            "model_link/linked.obj", "tex_link/cube/tex.png", "tex_link/passwd/pw.png",
                            "licence_link/LICENSE"}
    assert all("outside the library" in r for r in refused.values())
    assert run.stderr.count("rootlink") == 1  # said once, not one line per file under /
    broken = {b["reason"] for b in summary["broken_objects"]}
    buffers = {r for r in broken if r.startswith("buffer ")}
    assert len(buffers) == 2 and all("secret.bin" in r and "outside the library" in r for r in buffers), broken
    steps = broken - buffers  # a STEP that does not read: one line, no temporary file, no OpenCASCADE output
    assert steps == {"cannot read part empty.step: OpenCASCADE could not read empty.step as STEP",
                     "cannot read part garbage.step: OpenCASCADE could not read garbage.step as STEP"}, steps
    assert "ERR StepFile" not in run.stdout + run.stderr and "Failed to read STEP" not in run.stdout + run.stderr
    warnings = " | ".join(w["warning"] for w in summary["warnings"])
    for ref in ("../../../secret/secret.png", "..%2F..%2F..%2Fsecret%2Fsecret.png", "file:///", "secret.png in cube.mtl refused",
                "../../../secret/evil.mtl", "tex.png in cube.mtl refused", "pw.png in cube.mtl refused",
                "metadata.json not read", "secret.png in model.mtl refused"):
        assert ref in warnings, ref
    assert warnings.count("cube.urdf does not parse") == 2  # the bomb and the external entity
    assert "cube.urdf names the mesh ../../../outside/evil_model/cube.obj, outside the library" in warnings
    assert not summary["rescaled"]  # its scale describes the file outside: not applied to the cube beside it
    ignored = {i["entry"] for i in summary["ignored_metadata"]}
    assert {"metadata.json: parts 3", 'metadata.json: units "unknown"', "metadata.json: up_axis 7"} <= ignored
    assert not summary["failed"]


def test_nothing_from_outside_is_recorded_or_staged(hostile: dict) -> None:
    objects, lib, cat = hostile["objects"], hostile["lib"], hostile["cat"]
    for o in objects:
        path = Path(o["model_path"])
        assert path.is_relative_to(lib) or path.is_relative_to(cat), o["model_path"]
        assert not path.is_relative_to(lib) or os.path.realpath(path).startswith(str(lib)), o["model_path"]
    names = {o["name"] for o in objects}
    assert "Counted cube" in names and SECRET.decode() not in names
    assert [o["status"] for o in objects if "odd name [x] 'q' ü" in o["model_path"]] == ["active"]
    assert not any("dotted" in o["model_path"] for o in objects)  # a ..something folder is hidden: not walked
    active = [o for o in objects if o["status"] == "active"]
    assert len(active) == 20 and sum(o["status"] == "broken" for o in objects) == 4
    gso = [o for o in objects if o["name"] == "Cube_Scan"]
    assert [(o["status"], o["textured"]) for o in gso] == [("active", True)]  # its own texture kept, the bump not
    assert not any(SECRET.decode() in (o["license"] or "") for o in objects)
    boxes = [o for o in active if o["name"] == "box"]
    assert sorted(o["textured"] for o in boxes) == [False] * 5 + [True]  # the escaped images refused (GLB too)
    for o in boxes:  # each flagged with the reference and the reason
        said = [f["reason"] for f in o["flags"] if "refused" in f["reason"]]
        assert len(said) == (0 if o["textured"] else 1) and all("secret" in r and "outside the library" in r
                                                                  for r in said), o["flags"]
    for folder, _dirs, files in os.walk(cat):  # the catalog, its staged copies, collision meshes
        for name in files:
            path = Path(folder) / name
            data = path.read_bytes() if not path.is_symlink() else b""
            assert SECRET not in data and b"root:x:0:0" not in data, path
            if path.is_symlink():
                assert os.path.realpath(path).startswith(str(lib)), (path, os.path.realpath(path))


def test_nothing_outside_is_opened_or_listed(hostile: dict) -> None:
    tmp, lib = hostile["tmp"], hostile["lib"]
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    out = tmp / "audited"
    out.mkdir()
    run = subprocess.run([sys.executable, "-c", AUDITED, str(lib), str(out)], capture_output=True, text=True,
                         env=env, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    seen = json.loads(run.stdout.splitlines()[-1])
    touched = [p for p in seen if p.startswith((str(tmp / "secret"), str(tmp / "outside"), "/etc/passwd"))]
    assert not touched, touched
    assert any(p.startswith(str(lib)) for p in seen)  # the hook saw the library's own files


def test_a_link_to_the_root_of_the_file_system_costs_nothing(tmp_path: Path) -> None:
    lib = tmp_path / "L"
    (lib / "cube").mkdir(parents=True)
    (lib / "cube" / "cube.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    os.symlink("/", lib / "rootlink")
    refused: list[tuple[Path, str]] = []
    start = time.perf_counter()
    found = discover([lib], refused=refused)
    assert time.perf_counter() - start < 2.0
    assert [c.name for c in found] == ["cube"] and [p.name for p, _r in refused] == ["rootlink"]


def _tiny(lib: Path) -> Path:
    (lib / "cube").mkdir(parents=True)
    (lib / "cube" / "cube.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    return lib


def test_a_run_left_running_by_a_dead_process_is_closed_as_interrupted(tmp_path: Path, catalog) -> None:
    from mixcount.catalog.ingest import ingest_paths
    from mixcount.catalog.ingest_runs import note_running
    from mixcount.catalog.models import IngestRun
    from mixcount.config import load_config

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    with catalog.session() as s:
        rows = [IngestRun(status="running") for _ in range(3)]
        s.add_all(rows)
        s.commit()
        ids = [r.id for r in rows]
    note_running(catalog.data_dir, ids[1])  # this process: alive, left running
    notes = catalog.data_dir / "ingest_runs"
    (notes / f"{ids[2]}.json").write_text(json.dumps({"pid": int(gone.stdout), "started": None,
                                                      "host": os.uname().nodename}))  # a process that is gone
    summary = ingest_paths(catalog, [_tiny(tmp_path / "L")], config=load_config([], ["ingest.workers=1"]))
    assert summary.interrupted_runs == [ids[0], ids[2]]
    with catalog.session() as s:
        status = {r.id: r.status for r in s.query(IngestRun)}
    assert [status[i] for i in ids] == ["interrupted", "running", "interrupted"]
    assert status[summary.run_id] == "done" and not (notes / f"{summary.run_id}.json").exists()


def test_a_failure_of_the_run_exits_3_but_broken_input_exits_0(tmp_path: Path, monkeypatch) -> None:
    import mixcount.catalog.mesh as mesh
    from mixcount.cli import main

    lib = _tiny(tmp_path / "L")
    (lib / "empty").mkdir()
    (lib / "empty" / "empty.obj").write_text("")  # broken input: reported work, exit 0
    db = str(tmp_path / "c.db")
    assert main(["--db", db, "--set", "ingest.workers=1", "catalog", "ingest", str(lib)]) == 0

    def crash(**_kwargs):  # an internal error of the analysis, not of the file
        raise RuntimeError("simulated internal error")

    monkeypatch.setattr(mesh, "analyse_model", crash)
    (lib / "cube" / "cube.obj").write_text("v 0 0 0\nv 2 0 0\nv 0 2 0\nv 0 0 2\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    assert main(["--db", db, "--set", "ingest.workers=1", "catalog", "ingest", str(lib)]) == 3
