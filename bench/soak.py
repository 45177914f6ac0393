"""A soak of the compose run: N scenes with faults injected at random, as a run that lasts days meets them.

    nice -n 10 .venv/bin/python bench/soak.py                      # 100 scenes, 64 px, 1 sample, 12 faults
    nice -n 10 .venv/bin/python bench/soak.py --n 20 --faults 4    # a quick look
    .venv/bin/python bench/soak.py --smoke --work /tmp/soak        # 2 scenes at 32 px, 2 faults: the code path

The compose run is a child process (``compose_scenes`` on a generated 8-object demo library,
configs/quick.toml, ``--resolution`` px, ``--samples``, one worker, ``render_threads`` 1, no settle-ahead:
one bpy process to watch). While it runs, a seeded injector picks, every ``--every`` seconds on average,
one fault: SIGKILL or SIGSEGV of the render worker (mid-scene or between scenes, wherever it lands), or
SIGKILL of the compose process itself, which is then started again on the same OUT (a resume). After the
N scenes, one more phase composes into a 300 kB tmpfs in a private mount namespace (a full disk; skipped,
and said, where ``unshare -m`` is not allowed).

Figures (one JSON line at the end, and readable lines before it):

* ``scenes_lost`` - N minus the finished scene folders (must be 0), ``verify_ok`` - ``mixcount verify``;
* ``duplicates`` - merged COCO images naming the same file, or two scene folders of one seed (must be 0);
* ``failures_explained`` - share of ``OUT/logs/failures.jsonl`` lines with a known cause, and for a dead
  worker a kept log that holds its report (faulthandler's "Fatal Python error" for SIGSEGV) (must be 100 %);
  ``injected`` / ``failures`` / ``by_cause`` beside it;
* ``workers_gone_after_parent_kill_s`` - per compose kill, how long until none of its workers ran;
* ``worker_rss_mb`` - the render worker's resident memory at the first sample (bpy starting) and the last,
  the most, and each worker life's peak in start order (a worker lives until a fault or ``recycle_after``);
* ``disk_per_scene_kb`` - a finished scene folder's size on average; ``logs_kb`` - OUT/logs in all;
* ``full_disk`` - the tmpfs phase: exit code, its one line, whether a half scene was left.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Optional

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mixcount.worker.processes import child_pids, pid_running  # noqa: E402

CHILD = """
import json, sys
from pathlib import Path
from mixcount.config import load_config
from mixcount.demo.demo_pools import pool_from_demo_library
from mixcount.errors import MixcountError
from mixcount.run.compose import compose_scenes
args = json.loads(sys.argv[1])
cfg = load_config([Path(args["root"]) / "configs" / "quick.toml"], values=args["values"])
pool = pool_from_demo_library(Path(args["lib"]))
try:
    s = compose_scenes(pool=pool, config=cfg, out_dir=Path(args["out"]), assets_dir=Path(args["assets"]),
                       n=args["n"], progress=False)
except MixcountError as exc:
    print(f"error: {exc}", file=sys.stderr)
    sys.exit(2)
print(json.dumps({"written": s.written, "skipped": s.skipped, "failed": s.failed, "empty": s.empty,
                  "rejected": s.rejected}))
"""


def rss_mb(pid: int) -> Optional[float]:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def folder_kb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 1024 if path.exists() else 0.0


class Soak:
    """One soak: the compose child, the injector, the samples."""

    def __init__(self, args: argparse.Namespace, work: Path) -> None:
        self.args, self.work = args, work
        self.out = work / "out"
        self.rng = random.Random(args.seed)
        self.injected: dict[str, int] = {}
        self.gone_s: list[float] = []
        self.rss: list[float] = []
        self.peaks: dict[int, float] = {}  # worker pid -> its highest RSS sample (one entry per worker life)
        self.values = {"compose.resolution": args.resolution, "compose.samples": args.samples,
                       "compose.render_threads": 1, "compose.workers": 1, "compose.settle_ahead": False,
                       "compose.seed": 0, "compose.split": "train", "compose.max_attempts_factor": 3.0}

    def child(self, out: Path, n: int) -> subprocess.Popen[str]:
        payload = json.dumps({"root": str(ROOT), "lib": str(self.work / "demo"), "assets": str(self.work / "assets"),
                              "out": str(out), "n": n, "values": self.values})
        return subprocess.Popen([sys.executable, "-c", CHILD, payload], cwd=ROOT, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)

    def _fault(self, proc: subprocess.Popen[str]) -> Optional[str]:
        """Inject one fault into the running compose ``proc``: its kind, None when none could be (no worker)."""
        workers = [p for p in child_pids(proc.pid) if pid_running(p)]
        kind = self.rng.choice(["worker SIGKILL", "worker SIGSEGV", "worker SIGSEGV", "parent kill"])
        if kind != "parent kill" and not workers:
            return None  # between worker lives: try again later
        self.injected[kind] = self.injected.get(kind, 0) + 1
        if kind == "parent kill":
            t0 = time.monotonic()
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
            while any(pid_running(p) for p in workers) and time.monotonic() - t0 < 30:
                time.sleep(0.02)
            self.gone_s.append(round(time.monotonic() - t0, 3))
            for p in workers:  # none should be left; never leave one behind
                if pid_running(p):
                    os.kill(p, signal.SIGKILL)
            return kind
        os.kill(self.rng.choice(workers), signal.SIGKILL if kind == "worker SIGKILL" else signal.SIGSEGV)
        return kind

    def run(self) -> dict[str, Any]:
        args, faults_left, rounds = self.args, self.args.faults, 0
        while True:
            rounds += 1
            proc = self.child(self.out, args.n)
            next_fault = time.monotonic() + self.rng.uniform(0.5, 1.5) * args.every
            killed = False
            while proc.poll() is None:
                for p in child_pids(proc.pid):
                    mb = rss_mb(p)
                    if mb is not None and mb > 50:  # the bpy worker (not a shell or a helper)
                        self.rss.append(mb)
                        self.peaks[p] = max(self.peaks.get(p, 0.0), mb)
                        break
                if faults_left and time.monotonic() >= next_fault:
                    kind = self._fault(proc)
                    if kind is not None:
                        faults_left -= 1
                        next_fault = time.monotonic() + self.rng.uniform(0.5, 1.5) * args.every
                    killed = kind == "parent kill"
                    if killed:
                        break
                time.sleep(0.5)
            if killed:
                print(f"round {rounds}: compose process killed; workers gone after {self.gone_s[-1]} s; resuming",
                      file=sys.stderr, flush=True)
                continue
            stdout, stderr = proc.communicate()
            print(f"round {rounds}: compose exited {proc.returncode}: {stdout.strip()[-300:]}", file=sys.stderr,
                  flush=True)
            if proc.returncode == 0 or rounds > args.n:
                last = [ln for ln in stderr.splitlines() if ln.strip()][-1:] if proc.returncode else []
                return {"rounds": rounds, "last_rc": proc.returncode, "last_error": last[0][:500] if last else None}

    def full_disk(self) -> dict[str, Any]:
        """Compose into a 300 kB tmpfs in a private mount namespace: exit 2, one line, no half scene."""
        small = self.work / "small"
        small.mkdir()
        if subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode != 0:
            return {"skipped": "unshare -m is not allowed here"}
        payload = json.dumps({"root": str(ROOT), "lib": str(self.work / "demo"), "assets": str(self.work / "assets"),
                              "out": str(small), "n": 3, "values": {**self.values, "compose.seed": 1000}})
        cmd = (f"mount -t tmpfs -o size=300k tmpfs '{small}' && {sys.executable} -c '{CHILD}' '{payload}'; rc=$?; "
               f"echo LISTING; find '{small}' -mindepth 1 | sort; exit $rc")
        res = subprocess.run(["unshare", "-m", "sh", "-c", cmd], cwd=ROOT, capture_output=True, text=True, timeout=900)
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        left = res.stdout.split("LISTING", 1)[-1].split()
        return {"rc": res.returncode, "lines": len(lines), "line": lines[-1][:300] if lines else "",
                "half_scene_left": any(".tmp-" in f or "/scenes/scene_" in f for f in left)}


def explained(out: Path) -> dict[str, Any]:
    """Failure lines with a known cause (and, for a dead worker, a kept log holding its report)."""
    from mixcount.evaluate.run_health import read_failures

    lines = read_failures(out)
    ok = 0
    for r in lines:
        cause = str(r.get("cause") or "unknown")
        if cause == "unknown":
            continue
        if cause.startswith("worker "):
            log = Path(str(r.get("log") or ""))
            text = log.read_text(errors="replace") if log.is_file() else ""
            if cause == "worker SIGSEGV" and "Fatal Python error" not in text:
                continue
            if not log.is_file():
                continue
        ok += 1
    return {"failures": len(lines), "explained": ok,
            "failures_explained_pct": round(100.0 * ok / len(lines), 1) if lines else 100.0}


def figures(out: Path, n: int) -> dict[str, Any]:
    from mixcount.dataset.scene_writer import is_complete
    from mixcount.dataset.verify import verify_dataset
    from mixcount.evaluate.run_health import failures_by_cause

    scenes = [d for d in (out / "scenes").iterdir() if d.is_dir() and d.name.startswith("scene_") and is_complete(d)]
    seeds = [json.loads((d / "metadata.json").read_text())["seed"] for d in scenes]
    coco = json.loads((out / "annotations" / "instances_train.json").read_text())
    names = [img["file_name"] for img in coco["images"]]
    report = verify_dataset(out)
    return {"scenes_finished": len(scenes), "scenes_lost": max(0, n - len(scenes)),
            "duplicates": (len(names) - len(set(names))) + (len(seeds) - len(set(seeds))),
            "verify_ok": report.problems == 0, "verify_problems": report.lines(5),
            "disk_per_scene_kb": round(sum(folder_kb(d) for d in scenes) / max(1, len(scenes)), 1),
            "logs_kb": round(folder_kb(out / "logs"), 1), "by_cause": failures_by_cause(out)["by_cause"],
            **explained(out)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100, help="scenes to finish")
    ap.add_argument("--faults", type=int, default=12, help="faults to inject during the run")
    ap.add_argument("--every", type=float, default=25.0, help="mean seconds between faults")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0, help="seed of the fault injector")
    ap.add_argument("--work", type=Path, default=None,
                    help="work folder, kept (its demo/ and assets/ are reused; default: a temp folder, removed)")
    ap.add_argument("--smoke", action="store_true", help="2 scenes at 32 px, 2 faults 4 s apart: the code path only")
    args = ap.parse_args()
    if args.smoke:
        args.n, args.faults, args.every, args.resolution, args.samples = 2, 2, 4.0, 32, 1
    from mixcount.demo.library import generate_demo_library

    work = args.work or Path(tempfile.mkdtemp(prefix="mixcount-soak-"))
    work.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(work / "out", ignore_errors=True)  # a fresh run (the library and converted assets are kept)
    shutil.rmtree(work / "small", ignore_errors=True)
    try:
        if not (work / "demo").exists():
            generate_demo_library(work / "demo", seed=0, n_objects=8)
        soak = Soak(args, work)
        t0 = time.monotonic()
        run = soak.run()
        wall = time.monotonic() - t0
        figs = figures(soak.out, args.n)
        disk = soak.full_disk()
        rss = soak.rss
        result = {"bench": "soak", "smoke": bool(args.smoke), "n": args.n, "resolution": args.resolution, "samples": args.samples, "wall_s": round(wall, 1),
                  **run, "injected": soak.injected, "workers_gone_after_parent_kill_s": soak.gone_s,
                  "worker_rss_mb": {"first": round(rss[0], 1) if rss else None, "last": round(rss[-1], 1) if rss else None,
                                    "max": round(max(rss), 1) if rss else None, "samples": len(rss),
                                    "peak_per_worker_life": [round(v, 1) for v in soak.peaks.values()]},
                  **figs, "full_disk": disk}
        print(f"scenes lost {figs['scenes_lost']}, duplicates {figs['duplicates']}, failures explained "
              f"{figs['failures_explained_pct']} % ({figs['explained']}/{figs['failures']}), verify "
              f"{'ok' if figs['verify_ok'] else 'FAILED'}; injected {soak.injected}; workers gone after parent "
              f"kills {soak.gone_s} s; worker RSS first {result['worker_rss_mb']['first']} MB, last "
              f"{result['worker_rss_mb']['last']} MB, max {result['worker_rss_mb']['max']} MB; "
              f"{figs['disk_per_scene_kb']} kB per scene; full disk {disk}", file=sys.stderr)
        print(json.dumps(result))
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
