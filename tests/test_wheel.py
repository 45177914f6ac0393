"""A built wheel works outside the checkout: configs/, migrations/ and usd_templates/ ship inside it.

The wheel is built with pip (PEP 517, build isolation) and installed with ``--no-deps`` into a fresh
venv. The heavy dependencies (bpy, usd-core, ...) are the test venv's own, reached through a ``.pth``
line, so the test costs seconds instead of a 3 GB install; only mixcount itself comes from the wheel.
The commands then run from an empty directory, where no source tree can be found.
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_wheel_installs_and_runs_from_an_empty_directory(tmp_path: Path) -> None:
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(PROJECT_ROOT), "--no-deps", "-q", "-w", str(wheels)],
                   check=True, capture_output=True, text=True, timeout=600)
    (wheel,) = wheels.glob("mixcount-*.whl")

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    env_python = env_dir / "bin" / "python"
    env_site = Path(subprocess.run([str(env_python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                   check=True, capture_output=True, text=True).stdout.strip())
    deps = [p for p in site.getsitepackages() if Path(p).is_dir()]
    (env_site / "zz_mixcount_test_deps.pth").write_text("\n".join(deps) + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(env_python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)

    work = tmp_path / "empty"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MIXCOUNT_DB")}

    def mixcount(*args: str) -> subprocess.CompletedProcess[str]:
        proc = subprocess.run([str(env_dir / "bin" / "mixcount"), "--db", "cat.db", *args], cwd=work, env=env,
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"mixcount {' '.join(args)} failed:\n{proc.stderr[-3000:]}"
        return proc

    where = subprocess.run([str(env_python), "-c", "import mixcount, mixcount.resources as r; "
                            "print(mixcount.__file__); print(r.data_dir('migrations'))"],
                           cwd=work, env=env, check=True, capture_output=True, text=True).stdout.split()
    assert where[0].startswith(str(env_site)), "mixcount must come from the installed wheel"
    assert where[1].startswith(str(env_site)) and where[1].endswith("_data/migrations")

    mixcount("demo-library", "lib", "--n", "8")
    ingested = json.loads(mixcount("catalog", "ingest", "lib", "--json").stdout)
    assert ingested["new"] >= 8
    mixcount("catalog", "caption")
    mixcount("catalog", "split")
    plan = json.loads(mixcount("--config", "quick", "compose", "--dry-run", "--n", "2", "--split", "train", "--json").stdout)
    assert len(plan) == 2 and all(scene["n_counted"] > 0 for scene in plan)
