"""Faults no seed can fix stop a compose run with one line: a full disk, a read-only output folder, a
missing asset. No new seed is drawn after them, nothing half-written is left, finished scenes are kept.

The orchestration tests inject the fault behind the real scene task (``FakeWorker`` raising the OSError
a full disk gives, or failing the way bpy did on one, with its errno lost); the tmpfs and read-only
mount tests run the real CLI and real bpy on a real small or read-only file system (a private mount
namespace, so nothing outside the test sees it).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest
from test_compose_orchestration import FakeWorker, _pool

from mixcount.config import load_config
from mixcount.dataset.verify import verify_dataset
from mixcount.errors import AssetError, RenderError, StorageError
from mixcount.run.compose import compose_scenes
from mixcount.run.local import LocalExecutor
from mixcount.run.scene_task import run_scene_task

PROJECT_ROOT = Path(__file__).resolve().parent.parent


class FaultyWorker(FakeWorker):
    """A FakeWorker that writes part of its output and then fails as ``fault(seed)`` says (or not)."""

    def __init__(self, spec, fault: Callable[[int, Path], None], calls: list[int]) -> None:
        super().__init__(spec, lambda s: "ok", calls)
        self.fault = fault

    def run_scene_job(self, request, timeout=None):  # noqa: ANN001
        result = super().run_scene_job(request, timeout)
        self.fault(self.spec.seed, Path(request.out_dir))
        return result


@pytest.fixture()
def setup(tmp_path: Path):
    config = load_config(["quick"], values={"compose.seed": 300, "compose.split": "train"})
    return config, _pool(tmp_path), tmp_path / "out", tmp_path / "assets"


def compose(setup, n: int, calls: list[int], fault: Callable[[int, Path], None] = lambda s, d: None,
            workers: int = 1):
    config, pool, out, assets = setup
    runner = lambda task, _worker: run_scene_task(task, FaultyWorker(task.spec, fault, calls))  # noqa: E731
    with LocalExecutor(workers, runner=runner, recycle_after=0, settle_ahead=False) as executor:
        return compose_scenes(pool=pool, config=config, out_dir=out, assets_dir=assets, n=n, executor=executor)


def leftovers(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "scenes").glob(".tmp-*"))


def finished(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "scenes").iterdir() if p.is_dir() and not p.name.startswith("."))


@pytest.mark.parametrize("workers", [1, 2])
def test_no_space_raised_in_a_scene_stops_the_run(setup, workers: int) -> None:
    out = setup[2]

    def fault(seed: int, tmp: Path) -> None:
        if seed >= 302:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp / "rgb.png"))

    calls: list[int] = []
    with pytest.raises(StorageError) as caught:
        compose(setup, 5, calls, fault, workers=workers)
    message = str(caught.value)
    if workers == 1:
        assert calls == [300, 301, 302], "no seed may be drawn after a full disk"
    else:  # the scene in flight beside the failing one finishes (fails too here); none after is drawn
        assert 302 in calls and set(calls) <= {300, 301, 302, 303}
    assert "\n" not in message and message.startswith("no space left on device: ")
    assert str(out / "scenes") in message and "2 of 5 scene(s) finished and kept, no new seed drawn" in message
    assert finished(out) == ["scene_000300", "scene_000301"] and leftovers(out) == []
    assert not (out / "annotations").exists(), "no merge is attempted on a full disk"
    report = verify_dataset(out)
    assert report.scene_problems == [] and report.sound == 2


def test_full_disk_seen_only_as_missing_passes_stops_the_run(setup, monkeypatch) -> None:
    """bpy writes its passes without raising: a full disk reached the run as ``_ids.exr lacks passes``,
    no errno. The output folder's free space, probed after the failure, tells it apart."""
    out = setup[2]
    state = {"full": False}

    def fault(seed: int, tmp: Path) -> None:
        if seed == 301:
            state["full"] = True
            raise RenderError(f"worker: scene failed: {tmp}/_ids.exr lacks passes ['Object Index', 'Depth']\n"
                              "Traceback (most recent call last):\n  ...")

    from mixcount.run import faults

    real_free = faults.free_bytes
    monkeypatch.setattr(faults, "free_bytes", lambda folder: 150_000 if state["full"] else real_free(folder))
    calls: list[int] = []
    with pytest.raises(StorageError) as caught:
        compose(setup, 4, calls, fault)
    message = str(caught.value)
    assert calls == [300, 301]
    assert message.startswith(f"no space left on device: {out / 'scenes'} (150.0 kB free, a scene needs about ")
    assert "Traceback" not in message and "\n" not in message
    assert finished(out) == ["scene_000300"] and leftovers(out) == []


def test_a_bad_scene_still_regenerates(setup) -> None:
    """A failure that is not a storage fault (an error in one scene) keeps today's behaviour: the next
    seed is drawn and the run completes."""
    def fault(seed: int, tmp: Path) -> None:
        if seed == 300:
            raise RenderError("physics blew up: body 3 at 4e9 m")

    calls: list[int] = []
    summary = compose(setup, 2, calls, fault)
    assert calls == [300, 301, 302] and summary.written == 2 and summary.failed == 1 and summary.stopped is None


def test_read_only_folder_mid_run_stops_the_run(setup) -> None:
    out = setup[2]

    def fault(seed: int, tmp: Path) -> None:
        if seed == 301:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp / "coco.json"))

    calls: list[int] = []
    with pytest.raises(StorageError, match=r"^read-only file system: .*coco\.json; compose stopped with 1 of 3"):
        compose(setup, 3, calls, fault)
    assert calls == [300, 301] and finished(out) == ["scene_000300"] and leftovers(out) == []


@pytest.mark.parametrize("how", ["missing", "a folder, not a file"])
def test_a_missing_asset_stops_the_run_before_rendering(setup, how: str) -> None:
    config, pool, out, assets = setup
    gone = next(o for o in pool if o.name == "ball")
    Path(gone.model_path).unlink()
    if how != "missing":
        Path(gone.model_path).mkdir()  # unreadable as a model (root reads any file, whatever its mode)
    calls: list[int] = []
    with pytest.raises(AssetError) as caught:
        compose(setup, 3, calls)
    message = str(caught.value)
    first = int(message.split("scene scene_", 1)[1][:6])  # the first seed whose scene uses the ball
    assert calls == list(range(300, first)), "seeds before it render; none is drawn after it"
    assert f"model of object {gone.object_id} (ball) is {how}: {gone.model_path}" in message
    assert "no new seed drawn: restore the file or re-ingest its library" in message and "\n" not in message
    assert leftovers(out) == []


def test_a_full_disk_during_merge_is_one_line_and_keeps_the_old_merge(setup, monkeypatch, capsys) -> None:
    from mixcount.cli import main
    from mixcount.dataset import merge

    out = setup[2]
    compose(setup, 2, [])
    merged = out / "annotations" / "instances_train.json"
    before = merged.read_bytes()
    (out / "scenes" / "scene_000300" / "extra.txt").write_text("x")  # makes the merge stale

    def full(self, out_dir):  # noqa: ANN001 - _SplitWriter.finish, as a full disk ends it
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(merged) + ".tmp")

    monkeypatch.setattr(merge._SplitWriter, "finish", full)
    assert main(["merge", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"error: No space left on device: {merged}.tmp" and "Traceback" not in err
    assert merged.read_bytes() == before, "the previous merged file stays whole"
    assert not list((out / "annotations").glob(".merge-*")), "no temporary merge folder left"


def can_mount() -> list[str] | None:
    """The command prefix that gives a private mount namespace here (root: unshare -m; else a user
    namespace: unshare -rm), or None when neither works (then the fault is only injected above)."""
    if shutil.which("unshare") is None:
        return None
    for prefix in (["unshare", "-m"], ["unshare", "-rm"]):
        probe = subprocess.run([*prefix, "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt 2>/dev/null"],
                               capture_output=True)
        if probe.returncode == 0:
            return prefix
    return None


LISTING = "--- files left:"


def run_in_namespace(prefix: list[str], setup_sh: str, args: list[str], listed: Path) -> subprocess.CompletedProcess:
    """Run the CLI in a private mount namespace after ``setup_sh``; then list what ``listed`` holds
    (inside the namespace, so the listing shows the mounted file system) after ``LISTING`` on stdout."""
    cmd = " ".join([setup_sh, "&&", "{", sys.executable, "-m", "mixcount", *[f"'{a}'" for a in args],
                    "; rc=$?; echo '" + LISTING + "'; find", f"'{listed}'", "-mindepth 1 | sort; exit $rc; }"])
    return subprocess.run([*prefix, "sh", "-c", cmd], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=600)


def files_left(res: subprocess.CompletedProcess, root: Path) -> list[str]:
    return [Path(ln).relative_to(root).as_posix() for ln in res.stdout.split(LISTING, 1)[1].split()]


@pytest.mark.blender
def test_full_tmpfs_with_real_bpy_stops_with_one_line(composed_dataset: Path, tmp_path: Path) -> None:
    """The issue's case: composing into a 200 kB tmpfs. Real CLI, real bpy: one line naming the folder
    and the cause, exit 2, no seed after the first, nothing left on the small disk."""
    prefix = can_mount()
    if prefix is None:
        pytest.skip("no mount namespace here (unshare -m / -rm): the full disk is injected in the tests above")
    out = tmp_path / "small"
    out.mkdir()
    db = composed_dataset.parent / "catalog.db"
    res = run_in_namespace(prefix, f"mount -t tmpfs -o size=200k tmpfs '{out}'",
                           ["--db", str(db), "--config", "quick", "compose", "--n", "3", "--split", "train",
                            "--seed", "40", "--resolution", "96", "--samples", "2", "--out", str(out)], out)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    errors = [ln for ln in lines if ln.startswith("error:")]
    assert len(errors) == 1 and f"no space left on device: {out}" in errors[0], res.stderr
    assert "compose stopped with 0 of 3 scene(s) finished and kept, no new seed drawn" in errors[0]
    assert not any("scene_000041" in ln for ln in lines), "no seed after the first"
    left = files_left(res, out)
    assert not [f for f in left if ".tmp-" in f or f.startswith("scenes/scene_") or f.startswith("annotations")], left
    assert "scenes" in left, left  # the folders the run made, nothing half-written in them
    assert list(out.iterdir()) == [], "the tmpfs was private to the command"


@pytest.mark.blender
def test_read_only_output_folder_is_one_line_and_keeps_scenes(composed_dataset: Path, tmp_path: Path) -> None:
    """A finished dataset on a read-only file system (or a folder without write permission), asked for
    more scenes: one line, exit 2, nothing rendered, the scenes untouched."""
    out = tmp_path / "ro"
    shutil.copytree(composed_dataset, out, symlinks=True)  # OUT/assets' links to the catalog: broken here
    before = {p.relative_to(out).as_posix(): p.lstat().st_mtime_ns for p in out.rglob("*")}
    db = composed_dataset.parent / "catalog.db"
    args = ["--db", str(db), "--config", "quick", "compose", "--n", "3", "--split", "train", "--seed", "5",
            "--resolution", "96", "--out", str(out)]
    if os.geteuid() != 0:
        for p in [out, *out.rglob("*")]:
            if p.is_dir():
                p.chmod(0o555)
        try:
            res = subprocess.run([sys.executable, "-m", "mixcount", *args], cwd=PROJECT_ROOT, capture_output=True,
                                 text=True, timeout=600)
        finally:
            for p in [out, *out.rglob("*")]:
                if p.is_dir():
                    p.chmod(0o755)
        cause = "permission denied"
    else:
        prefix = can_mount()
        if prefix is None:
            pytest.skip("root without a mount namespace cannot make a folder read-only")
        res = run_in_namespace(prefix, f"mount --bind '{out}' '{out}' && mount -o remount,bind,ro '{out}'", args, out)
        cause = "read-only file system"
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert errors == [f"error: {cause}: {out / 'scenes'}; nothing was rendered"], res.stderr
    assert {p.relative_to(out).as_posix(): p.lstat().st_mtime_ns for p in out.rglob("*")} == before
    assert verify_dataset(out).problems == 0
    assert json.loads((out / "dataset.json").read_text())["counts"]["scenes"] == 2
