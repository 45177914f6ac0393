"""The catalog steps on a local two-node Ray cluster against the local executor (issue 69, item 2).

    nice -n 10 .venv/bin/python bench/ray_catalog.py --n 24          # a demo library of 24 ordinary objects
    .venv/bin/python bench/ray_catalog.py --libraries 23 --kill-step filter   # 23 whole demo libraries: 2,001 objects
    .venv/bin/python bench/ray_catalog.py --smoke --work /tmp/rc     # 1 ordinary object, ingest only

A seed-0 demo library (``mixcount demo-library --n N``: N ordinary objects plus their traps and
containers) is ingested, rendered (64 px, 2 spp), filtered and captioned (stub) three times, each step a
``mixcount`` process as a user runs it:

1. ``local``: the local executor (``ingest.workers`` / ``canonical_render.workers`` as configured);
2. ``ray``: ``--executor ray --address`` on a cluster of two ``ray start`` processes on this machine (a head
   and a second node, ``--cpus`` CPUs each);
3. ``ray_killed``: as 2 on a fresh catalog, the second node SIGKILLed while it runs a task of
   ``--kill-step`` (render by default); that step and the ones after it finish on the head.

``--libraries K`` (issue 69's "2,000 light objects"): K whole demo libraries of seeds 0..K-1, each in a
folder of its own under one library root (87 catalog objects each: 23 give 2,001), instead of one library
of ``--n`` objects. ``--kill-in-ray-run``: no third run; the second node is killed in the ``ray`` run itself
(the steps before ``--kill-step`` are then clean two-node figures), for a size where three runs do not fit.

Figures (readable lines, then one JSON line): objects, wall seconds per step and in all for each run, seconds
per object, whether each Ray catalog equals the local one (``catalog list --json``: objects, facts, flags
with their reasons, statuses, captions; timestamps and the catalog's own folder aside) and how many
objects differ, each step's exit code.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.test_ray_catalog import OPTS, VOLATILE, Node  # noqa: E402  (the test's second node)
from tests.test_ray_executor import ENV, MIX, Cluster  # noqa: E402  (a head on 127.0.0.1, killed by pid)

STEPS = ("ingest", "render", "filter", "caption")
TASK_OF_STEP = {"ingest": "run_analysis", "render": "render_chunk", "filter": "pair_figures",
                "caption": "caption_task"}  # the Ray task whose run on the second node is the moment to kill it


def mix(db: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(MIX), "--db", str(db), *OPTS, *args], capture_output=True, text=True, env=ENV,
                          cwd=ROOT, timeout=7200)


def documents(db: Path) -> list[dict[str, Any]]:
    got = mix(db, "catalog", "list", "--json")
    text = got.stdout.replace(str(db.parent), "DB")
    return [{k: v for k, v in o.items() if k not in VOLATILE} for o in json.loads(text)]


def step_args(step: str, library: Path) -> list[str]:
    return ["catalog", step, str(library)] if step == "ingest" else ["catalog", step]


def load() -> float:
    """The 1-minute load average: what else ran on the machine during a step."""
    return round(os.getloadavg()[0], 2)


def run(db: Path, library: Path, steps: tuple[str, ...], extra: list[str], kill: Node | None = None,
        kill_step: str = "render") -> dict[str, Any]:
    """Each step once; ``kill``: that node is SIGKILLed while it runs a task of ``kill_step``."""
    db.parent.mkdir(parents=True)
    seconds: dict[str, float] = {}
    codes: dict[str, int] = {}
    loads: dict[str, float] = {}
    killed_at = None
    for step in steps:
        t0 = time.perf_counter()
        print(f"  {db.parent.name}: {step} ...", file=sys.stderr, flush=True)
        if step == kill_step and kill is not None:
            proc = subprocess.Popen([str(MIX), "--db", str(db), *OPTS, *step_args(step, library), *extra], env=ENV,
                                    cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            while proc.poll() is None and not kill.running(TASK_OF_STEP[step]):
                time.sleep(0.2)
            if proc.poll() is None:
                kill.kill()
                killed_at = round(time.perf_counter() - t0, 1)
            proc.communicate()
            codes[step] = proc.returncode
        else:
            codes[step] = mix(db, *step_args(step, library), *extra).returncode
        seconds[step] = round(time.perf_counter() - t0, 1)
        loads[step] = load()
        print(f"  {db.parent.name}: {step} done in {seconds[step]} s, exit {codes[step]}, load {loads[step]}",
              file=sys.stderr, flush=True)
    return {"seconds": seconds, "total_s": round(sum(seconds.values()), 1), "exit": codes, "load_after": loads,
            **({"node_killed_after_s": killed_at} if kill is not None else {})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=24, help="ordinary objects of the demo library")
    ap.add_argument("--cpus", type=int, default=1, help="CPUs of each of the two nodes")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--no-kill", action="store_true", help="skip the run with a node killed")
    ap.add_argument("--libraries", type=int, default=0, help="K whole demo libraries (seeds 0..K-1) instead of --n")
    ap.add_argument("--kill-step", choices=STEPS, default="render", help="the step during which the node is killed")
    ap.add_argument("--kill-in-ray-run", action="store_true", help="kill the node in the ray run, no third run")
    ap.add_argument("--smoke", action="store_true", help="1 ordinary object, ingest only, no kill: the code path")
    a = ap.parse_args()
    steps = ("ingest",) if a.smoke else STEPS
    n = 1 if a.smoke else a.n
    work = a.work or Path(tempfile.mkdtemp(prefix="raycat-"))
    from mixcount.demo.library import generate_demo_library

    library = work / "lib"
    if a.libraries and not a.smoke:
        for seed in range(a.libraries):
            generate_demo_library(library / f"seed{seed:02d}", seed=seed, n_objects=None)
    else:
        generate_demo_library(library, seed=0, n_objects=n)
    head = Cluster(cpus=a.cpus)
    node = None
    try:
        node = Node(head)
        ray = ["--executor", "ray", "--address", head.address]
        runs = {"local": run(work / "local" / "catalog.db", library, steps, [])}
        if a.kill_in_ray_run and not a.smoke:
            runs["ray"] = run(work / "ray" / "catalog.db", library, steps, ray, kill=node, kill_step=a.kill_step)
        else:
            runs["ray"] = run(work / "ray" / "catalog.db", library, steps, ray)
            if not (a.smoke or a.no_kill):
                runs["ray_killed"] = run(work / "ray_killed" / "catalog.db", library, steps, ray, kill=node,
                                         kill_step=a.kill_step)
    finally:
        if node is not None and node.proc.poll() is None:
            node.kill()
        head.kill()
    local = documents(work / "local" / "catalog.db")
    for name, r in runs.items():
        docs = local if name == "local" else documents(work / name / "catalog.db")
        r["objects"] = len(docs)
        r["s_per_object"] = round(r["total_s"] / max(1, len(docs)), 2)
        if name != "local":
            r["same_catalog"] = docs == local
            r["objects_differing"] = sum(1 for x, y in zip(docs, local) if x != y) + abs(len(docs) - len(local))
        print(f"{name}: {r['objects']} objects, {r['total_s']} s ({r['s_per_object']} s/object; "
              + ", ".join(f"{s} {t} s" for s, t in r["seconds"].items()) + ")"
              + (f"; same catalog as local: {r['same_catalog']}" if name != "local" else "")
              + (f"; node killed after {r['node_killed_after_s']} s of {a.kill_step}" if "node_killed_after_s" in r else "")
              + "; exit codes " + ", ".join(f"{s} {c}" for s, c in r["exit"].items()))
    print(json.dumps({"bench": "ray_catalog", "n": n, "libraries": a.libraries, "kill_step": a.kill_step, "nodes": 2, "cpus_per_node": a.cpus, "steps": list(steps),
                      "flags": sum(len(o["flags"]) for o in local), "runs": runs}, sort_keys=True))


if __name__ == "__main__":
    main()
