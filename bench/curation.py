"""`catalog filter` on the generated demo library: time (cold and warm descriptor cache) and the ground-truth figures.

Usage: .venv/bin/python bench/curation.py [--work DIR] [--reps 3] [--objects N] [--pythonpath TREE] [--smoke]
           [--compare-work DIR2 --compare-pythonpath OLD_TREE]

``--work DIR`` is reused when it already holds a rendered library (``DIR/db_rendered``); otherwise the demo
library (seed 0) is generated there, ingested and rendered at 64 px / 2 spp as tests/test_curate_demo.py
does (bpy, about a minute); ``--objects N`` generates N ordinary objects instead of all 58 (``demo-library
--n``; every trap is still planted). ``--smoke`` (the suite's run) is one repetition on 8 ordinary objects at
16 px / 1 spp: 21 objects whose cold filter takes seconds, where the whole library's takes minutes (and
tests/test_curate_demo.py already filters the whole library). Each repetition copies the rendered catalog, deletes its descriptor cache and
runs ``mixcount catalog filter --json`` twice: ``cold`` (every descriptor computed, what a first
``make demo`` pays) and ``warm`` (descriptors cached). Wall and CPU seconds of the filter process are
recorded. With ``--compare-work`` / ``--compare-pythonpath`` a second arm runs interleaved with the first
(cold A, cold B, warm A, warm B per repetition) with ``PYTHONPATH=OLD_TREE``: a checkout of older code
(``git archive <commit> mixcount configs migrations | tar -x -C OLD_TREE``) on its own library, so the two are timed
in one session on a shared machine. Prints human lines to stderr and one JSON line to stdout:
{"arms": [{"label", "objects", "cold_wall_s", "warm_wall_s", "cold_cpu_s", "warm_cpu_s", "median_*",
"precision", "recall", "clean_flag_rate", "by_trap"}], "ratio_median_cold_wall": ..., ...}
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
QUICK = REPO / "configs" / "quick.toml"


def _mixcount(db: Path, *args: str, env: dict[str, str] | None = None, cwd: Path) -> tuple[float, float, str]:
    """Run the CLI in a child process from ``cwd`` (never the repository root, so PYTHONPATH decides
    which code runs); returns (wall s, CPU s, stdout)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "mixcount.cli", "--db", str(db), *args], cwd=cwd, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"mixcount {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, proc.stdout


def prepare(work: Path, env: dict[str, str], px: int = 64, spp: int = 2, objects: int = 0) -> Path:
    """``work/db_rendered``: the demo library (``objects`` ordinary objects, 0 = all) generated, ingested and
    rendered at ``px`` / ``spp`` (once)."""
    rendered = work / "db_rendered"
    if (rendered / "catalog.db").is_file():
        return rendered
    work.mkdir(parents=True, exist_ok=True)
    db = work / "db" / "catalog.db"
    shutil.rmtree(db.parent, ignore_errors=True)
    db.parent.mkdir(parents=True)
    base = ["--config", str(QUICK), "--set", f"canonical_render.resolution={px}", "--set", f"canonical_render.samples={spp}"]
    for step in (["demo-library", str(work / "demo"), "--n", str(objects)], ["catalog", "ingest", str(work / "demo")], ["catalog", "render"]):
        wall, _, _ = _mixcount(db, *base, *step, env=env, cwd=work)
        print(f"{work}: {' '.join(step[:2])} {wall:.1f} s", file=sys.stderr)
    shutil.copytree(db.parent, rendered)
    return rendered


class Arm:
    def __init__(self, label: str, work: Path, env: dict[str, str], px: int = 64, spp: int = 2, objects: int = 0) -> None:
        self.label, self.work, self.env = label, work, env
        self.rendered = prepare(work, env, px, spp, objects)
        self.times: dict[str, list[float]] = {"cold_wall_s": [], "warm_wall_s": [], "cold_cpu_s": [], "warm_cpu_s": []}
        self.summary: dict | None = None
        self.scratch: Path | None = None

    def fresh(self, tmp: Path) -> None:
        self.scratch = tmp / f"{self.label}-{len(self.times['cold_wall_s'])}"
        shutil.copytree(self.rendered, self.scratch)
        shutil.rmtree(self.scratch / "descriptors", ignore_errors=True)

    def run(self, phase: str) -> None:
        assert self.scratch is not None
        wall, cpu, out = _mixcount(self.scratch / "catalog.db", "catalog", "filter", "--json", env=self.env, cwd=self.work)
        self.times[f"{phase}_wall_s"].append(round(wall, 2))
        self.times[f"{phase}_cpu_s"].append(round(cpu, 2))
        self.summary = json.loads(out)
        print(f"{self.label} {phase}: {wall:.1f} s wall, {cpu:.1f} s CPU", file=sys.stderr)

    def report(self) -> dict:
        gt = (self.summary or {}).get("ground_truth") or {}
        out = {"label": self.label, "objects": (self.summary or {}).get("objects"), **self.times}
        out.update({f"median_{k}": statistics.median(v) for k, v in self.times.items() if v})
        out.update({k: gt.get(k) for k in ("precision", "recall", "clean_flag_rate", "pairs_planted",
                                           "pairs_predicted", "pairs_correct", "missed_pairs", "false_pairs")})
        out["by_trap"] = {k: {f: v[f] for f in ("planted", "found", "recall", "precision")}
                          for k, v in (gt.get("by_trap") or {}).items()}
        return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "mixcount-bench-curation")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--pythonpath", type=Path, help="run the first arm from this tree too (a frozen copy)")
    parser.add_argument("--compare-work", type=Path)
    parser.add_argument("--compare-pythonpath", type=Path)
    parser.add_argument("--objects", type=int, help="ordinary objects in the generated library (demo-library --n; "
                        "default all 58, 8 with --smoke); the traps are planted whatever the number")
    parser.add_argument("--smoke", action="store_true",
                        help="seconds: 8 ordinary objects, renders at 16 px / 1 spp, one repetition (the suite)")
    args = parser.parse_args()
    px, spp = (16, 1) if args.smoke else (64, 2)
    if args.smoke:
        args.reps = 1
    if args.objects is None:
        args.objects = 8 if args.smoke else 0
    if (args.compare_work is None) != (args.compare_pythonpath is None):
        parser.error("--compare-work and --compare-pythonpath go together")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    first = env if args.pythonpath is None else {**env, "PYTHONPATH": str(args.pythonpath.resolve())}
    arms = [Arm("current", args.work.resolve(), first, px, spp, args.objects)]
    if args.compare_work is not None:
        if not (args.compare_pythonpath / "mixcount" / "__init__.py").is_file():
            parser.error(f"{args.compare_pythonpath} holds no mixcount/ package")
        arms.append(Arm("compare", args.compare_work.resolve(), {**env, "PYTHONPATH": str(args.compare_pythonpath.resolve())},
                        objects=args.objects))
    with tempfile.TemporaryDirectory(prefix="mixcount-bench-curation-") as tmp:
        for _ in range(args.reps):
            for arm in arms:
                arm.fresh(Path(tmp))
            for phase in ("cold", "warm"):
                for arm in arms:
                    arm.run(phase)
            for arm in arms:
                shutil.rmtree(arm.scratch, ignore_errors=True)  # type: ignore[arg-type]
    result: dict = {"arms": [arm.report() for arm in arms], "reps": args.reps, "ordinary_objects": args.objects}  # 0: all
    if len(arms) == 2:
        a, b = result["arms"]
        for key in ("cold_wall_s", "warm_wall_s", "cold_cpu_s", "warm_cpu_s"):
            result[f"ratio_median_{key}"] = round(a[f"median_{key}"] / b[f"median_{key}"], 3)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
