"""The CLI never shows a traceback: usage errors print the usage line and one error line and exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest

import mixcount
from mixcount.cli import main

USAGE_ERRORS = {
    "value out of range": (["compose", "--n", "0"], "Invalid value for '--n'"),
    "not an integer": (["compose", "--n", "abc"], "Invalid value for '--n'"),
    "unknown command": (["frob"], "No such command 'frob'"),
    "unknown option": (["compose", "--bogus"], "No such option: --bogus"),
    "missing argument": (["catalog", "show"], "Missing argument 'ID'"),
    "unknown sub-command": (["catalog", "frob"], "No such command 'frob'"),
}


@pytest.mark.parametrize("kind", sorted(USAGE_ERRORS))
def test_usage_error_prints_usage_and_one_error_line(kind: str, capsys: pytest.CaptureFixture[str]) -> None:
    argv, message = USAGE_ERRORS[kind]
    code = main(argv)
    captured = capsys.readouterr()
    err = captured.err
    assert code == 2
    assert "Traceback" not in err and "Traceback" not in captured.out
    assert err.lstrip().startswith("Usage: mixcount")
    error_lines = [line for line in err.splitlines() if line.startswith("Error:")]
    assert len(error_lines) == 1 and message in error_lines[0]


def test_config_error_is_one_line_exit_2(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["--db", str(tmp_path / "c.db"), "--set", "scene.no_such_key=1", "catalog", "list"])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    assert "unknown config key 'scene.no_such_key'" in err
    assert len(err.strip().splitlines()) == 1


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"mixcount {mixcount.__version__}"
    assert mixcount.__version__[0].isdigit()


def test_console_script_usage_error_has_no_traceback() -> None:
    """The real entry point in a subprocess: stderr holds the usage and the error, nothing else."""
    proc = subprocess.run([sys.executable, "-m", "mixcount", "compose", "--n", "-3"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "Usage: mixcount compose" in proc.stderr and "Invalid value for '--n'" in proc.stderr


def test_version_is_read_only_when_asked() -> None:
    """Every mixcount process imports the package; the version lookup (importlib.metadata scanning the
    installed distributions, ~25 ms) happens only for ``--version`` and the export manifests."""
    import subprocess
    import sys

    code = ("import sys, mixcount.cli; print('importlib.metadata' in sys.modules); "
            "from mixcount.version import __version__; print(__version__ == mixcount.__version__ != '')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["False", "True"]
