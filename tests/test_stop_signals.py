"""A long catalog command stopped by Ctrl-C (SIGINT) or by SIGTERM (``kill``, ``docker stop``, Slurm) ends
at once with one "stopped" line and exit 130 / 143, keeps what it computed (the filter's figure cache), and
leaves the catalog as it was: locally (forked worker processes) and on a Ray cluster, whose ``ray.init``
installs a SIGTERM handler of its own (mixcount.stop_signals).

The commands run as subprocesses on a copy of the rendered demo catalog and are stopped once the filter's
second phase (``filter: primitive fits``) has started: its descriptors are then written and its first
figures known."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path
from typing import Iterator

import pytest
from conftest import RENDERED_DEMO

from tests.test_ray_executor import ENV, MIX, Cluster

REPO = Path(__file__).resolve().parent.parent
PHASE = "filter: primitive fits"


def _as_in_a_terminal() -> None:
    """The child's SIGINT as an interactive shell leaves it. A background job of a script (``pytest &``,
    ``make test &``) starts with SIGINT ignored, and a child inherits that (POSIX), so Ctrl-C would never
    reach the command under test there."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _copy(rendered: Path, dest: Path) -> Path:
    shutil.copytree(rendered, dest, ignore=shutil.ignore_patterns("descriptors"))
    return dest / "catalog.db"


def _flags(db: Path) -> int:
    got = subprocess.run([str(MIX), "--db", str(db), "catalog", "list", "--json"], capture_output=True, text=True,
                         env=ENV, cwd=REPO, timeout=300)
    assert got.returncode == 0, got.stderr
    return sum(len(o["flags"]) for o in json.loads(got.stdout))


def _stop_filter(db: Path, sig: signal.Signals, *extra: str) -> tuple[int, str, str, float]:
    """``catalog filter`` on ``db``, sent ``sig`` once its primitive fits have started: (exit code, stdout,
    stderr, seconds from the signal to its exit)."""
    err_path, out_path = db.parent / "filter.err", db.parent / "filter.out"
    with err_path.open("w") as err, out_path.open("w") as out:
        proc = subprocess.Popen([str(MIX), "--db", str(db), *RENDERED_DEMO, "--set", "filter.workers=2",
                                 "catalog", "filter", *extra], stdout=out, stderr=err, env=ENV, cwd=REPO,
                                preexec_fn=_as_in_a_terminal)
        try:
            deadline = time.monotonic() + 400
            while PHASE not in err_path.read_text():
                assert proc.poll() is None, err_path.read_text()[-2000:]
                assert time.monotonic() < deadline, "the filter never reached its primitive fits"
                time.sleep(0.1)
            sent = time.monotonic()
            proc.send_signal(sig)
            code = proc.wait(timeout=180)
            took = time.monotonic() - sent
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return code, out_path.read_text(), err_path.read_text(), took


def _assert_stopped(db: Path, code: int, out: str, err: str, *, expected: int, line: str, flags_before: int) -> None:
    assert code == expected, err[-2000:]
    assert err.strip().splitlines()[-1] == line, err[-2000:]
    assert "Traceback" not in err
    assert "flags:" not in out  # the summary of a finished filter never printed
    figures = [json.loads(p.read_text()) for p in (db.parent / "descriptors").glob("layouts_*.json")]
    assert figures and len(figures[0]) > 0, "the figures computed before the stop were not kept"
    assert _flags(db) == flags_before  # the catalog is as it was: no flag of a half-run filter written


@pytest.fixture(scope="module")
def ray_head() -> Iterator[Cluster]:
    head = Cluster(cpus=2)
    try:
        yield head
    finally:
        head.kill()
        assert not head.leftovers()


def test_sigterm_stops_a_local_filter_keeping_its_figures(rendered_demo_catalog: tuple[Path, dict],
                                                          tmp_path: Path) -> None:
    db = _copy(rendered_demo_catalog[0], tmp_path / "db")
    before = _flags(db)
    code, out, err, took = _stop_filter(db, signal.SIGTERM)
    _assert_stopped(db, code, out, err, expected=143, line="stopped by SIGTERM", flags_before=before)
    print(f"local filter: exit {code} {took:.1f} s after SIGTERM")


@pytest.mark.parametrize("sig, expected, line", [(signal.SIGINT, 130, "stopped by the user"),
                                                 (signal.SIGTERM, 143, "stopped by SIGTERM")],
                         ids=["sigint", "sigterm"])
def test_a_ray_filter_stops_on_ctrl_c_and_on_sigterm(ray_head: Cluster, rendered_demo_catalog: tuple[Path, dict],
                                                     tmp_path: Path, sig: signal.Signals, expected: int,
                                                     line: str) -> None:
    db = _copy(rendered_demo_catalog[0], tmp_path / "db")
    before = _flags(db)
    code, out, err, took = _stop_filter(db, sig, "--executor", "ray", "--address", ray_head.address)
    _assert_stopped(db, code, out, err, expected=expected, line=line, flags_before=before)
    print(f"ray filter: exit {code} {took:.1f} s after {sig.name}")


def test_sigterm_handler_is_the_commands_alone() -> None:
    """Held only for the block; a forked child that inherits it ends as SIGTERM's default (killed by the
    signal), not by raising into its copy of the command."""
    from mixcount.stop_signals import stop_on_sigterm, stopped_by

    before = signal.getsignal(signal.SIGTERM)
    with stop_on_sigterm():
        assert signal.getsignal(signal.SIGTERM) is not before
        pid = os.fork()
        if pid == 0:  # the child: wait for the signal; reaching the exit means it was swallowed
            try:
                time.sleep(30)
            finally:
                os._exit(7)
        time.sleep(0.2)
        os.kill(pid, signal.SIGTERM)
        _, status = os.waitpid(pid, 0)
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises here, at the next bytecode
        assert stopped_by() == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is before
