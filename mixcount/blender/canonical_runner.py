"""Parent side of the canonical-render workers (no bpy here): start, watch, kill on a hang, restart.

:func:`run_jobs` splits the jobs over ``workers`` long-lived worker processes
(``python -m mixcount.blender.canonical_job``). Each worker appends start/done/failed lines to its own
results file; a watcher thread per worker reads them. A job that runs longer than ``timeout_s`` gets its
worker killed, is reported as failed ("timed out"), and a fresh worker carries on with the jobs after it;
a worker that dies mid-job (segfault, out of memory) is handled the same way. Results reach the caller
through ``on_result(key, record)`` on the calling thread, so the caller may write to its database there.
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

POLL_S = 0.1
STARTUP_GRACE_S = 60.0  # bpy import + first factory reset, on top of the per-job timeout


def _tail(path: Path, n: int = 1200) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return ""
    lines = [ln for ln in text.splitlines() if ln.strip() and "| INFO:" not in ln]
    return "\n".join(lines)[-n:]


def _run_chunk(jobs: list[dict[str, Any]], *, timeout_s: float, work_dir: Path, tag: str,
               out: "queue.Queue[tuple[str, dict[str, Any]]]", stop: threading.Event) -> None:
    """Run ``jobs`` in one worker process at a time until every job is done or failed."""
    remaining = list(jobs)
    round_no = 0
    while remaining and not stop.is_set():
        round_no += 1
        jobs_file = work_dir / f"jobs_{tag}_{round_no}.json"
        results_file = work_dir / f"results_{tag}_{round_no}.jsonl"
        log_file = work_dir / f"worker_{tag}_{round_no}.log"
        jobs_file.write_text(json.dumps(remaining))
        results_file.touch()
        with open(log_file, "wb") as log:
            proc = subprocess.Popen(
                [sys.executable, "-m", "mixcount.blender.canonical_job", str(jobs_file), str(results_file)],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
            )
        finished: set[str] = set()
        current: str | None = None
        started_at = time.monotonic()
        round_start = started_at
        pos = 0
        buf = ""
        killed_for: str | None = None
        try:
            while True:
                exited = proc.poll() is not None  # checked before reading, so no last line is missed
                with open(results_file, encoding="utf-8") as fh:
                    fh.seek(pos)
                    chunk = fh.read()
                    pos = fh.tell()
                buf += chunk
                *lines, buf = buf.split("\n")
                for line in lines:
                    if not line.strip():
                        continue
                    rec = json.loads(line)
                    if rec["event"] == "start":
                        current, started_at = rec["key"], time.monotonic()
                    else:
                        finished.add(rec["key"])
                        current = None
                        out.put((rec["key"], rec))
                if exited and not chunk:
                    break
                now = time.monotonic()
                if stop.is_set():
                    proc.kill()
                    proc.wait()
                    return
                if current is not None and now - started_at > timeout_s:
                    killed_for = current
                    proc.kill()
                    proc.wait()
                    break
                if current is None and not finished and now - round_start > timeout_s + STARTUP_GRACE_S:
                    killed_for = "<startup>"
                    proc.kill()
                    proc.wait()
                    break
                time.sleep(POLL_S)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        if killed_for == "<startup>":
            err = f"render worker did not start within {timeout_s + STARTUP_GRACE_S:.0f} s"
            for job in remaining:
                out.put((job["key"], {"key": job["key"], "event": "failed", "error": err}))
            return
        if killed_for is not None:
            out.put((killed_for, {"key": killed_for, "event": "failed",
                                  "error": f"render timed out after {timeout_s:g} s (worker killed)"}))
            finished.add(killed_for)
        elif current is not None:  # the worker died inside a job
            err = f"render worker exited with code {proc.returncode} during this object"
            tail = _tail(log_file)
            out.put((current, {"key": current, "event": "failed", "error": f"{err}: {tail}" if tail else err}))
            finished.add(current)
        elif not finished and remaining:  # died before the first job: bpy missing, bad environment
            err = f"render worker exited with code {proc.returncode} before rendering: {_tail(log_file)}"
            for job in remaining:
                out.put((job["key"], {"key": job["key"], "event": "failed", "error": err}))
            return
        remaining = [j for j in remaining if j["key"] not in finished]


def run_jobs(jobs: list[dict[str, Any]], *, on_result: Callable[[str, dict[str, Any]], None],
             workers: int, timeout_s: float, threads_per_worker: int) -> None:
    """Render ``jobs`` (dicts with a unique ``key``) in ``workers`` processes; call ``on_result`` once
    per job with its done/failed record, on this thread, as results arrive."""
    if not jobs:
        return
    workers = max(1, min(int(workers), len(jobs)))
    if threads_per_worker <= 0 and workers > 1:
        threads_per_worker = max(1, (os.cpu_count() or 1) // workers)
    jobs = [{**j, "threads": threads_per_worker} for j in jobs]
    results: "queue.Queue[tuple[str, dict[str, Any]]]" = queue.Queue()
    stop = threading.Event()
    with tempfile.TemporaryDirectory(prefix="mixcount-canonical-") as tmp:
        work_dir = Path(tmp)
        threads = [
            threading.Thread(target=_run_chunk, daemon=True,
                             kwargs=dict(jobs=jobs[w::workers], timeout_s=timeout_s, work_dir=work_dir,
                                         tag=str(w), out=results, stop=stop))
            for w in range(workers)
        ]
        for t in threads:
            t.start()
        seen = 0
        try:
            while seen < len(jobs):
                try:
                    key, rec = results.get(timeout=0.5)
                except queue.Empty:
                    if not any(t.is_alive() for t in threads) and results.empty():
                        break
                    continue
                seen += 1
                on_result(key, rec)
        finally:
            stop.set()
            for t in threads:
                t.join(timeout=10)
