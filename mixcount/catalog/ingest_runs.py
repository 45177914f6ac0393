"""The record of an ingest run that is still going, and what the next run does with one that is not.

An ingest killed mid-run (``kill -9``, a power cut) cannot close its ``ingest_runs`` row: it stayed
``running`` forever. Each run therefore leaves a note beside the catalog while it runs
(``<data_dir>/ingest_runs/<id>.json``: its process id, the process's start time and the host), and the next
ingest closes every ``running`` row whose process is gone as ``interrupted``: a note of this host whose
process no longer runs (or is another process with the same id), or no note at all (a run from before
these notes). A row whose note names another host is left as it is: its process cannot be checked from
here. docs/ingest.md, "Interrupted runs and exit codes".

Which broken objects are a failure of the run itself, not of their input (:func:`run_failure`), is
decided here too: those make ``catalog ingest`` exit non-zero.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.models import IngestRun, utcnow

RUN_NOTES = "ingest_runs"

# broken reasons that are the run's own failure (a worker crash, an error of mixcount or a library it
# uses, memory), not a property of the input file: see mixcount.catalog.analysis_pool.run_analysis
RUN_FAILURES = ("mesh analysis failed:", "mesh analysis crashed", "out of memory")


def run_failure(reason: str) -> bool:
    """Whether a broken object's ``reason`` is a failure of the run rather than of its input."""
    return reason.startswith(RUN_FAILURES)


def _started(pid: int) -> str | None:
    """The start time of process ``pid`` (Linux: /proc/<pid>/stat field 22), None where unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rpartition(")")[2].split()[19]


def _alive(pid: int, started: str | None) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    now = _started(pid)
    return started is None or now is None or now == started


def _note(data_dir: Path, run_id: int) -> Path:
    return Path(data_dir) / RUN_NOTES / f"{run_id}.json"


def note_running(data_dir: Path, run_id: int | None) -> None:
    """Leave the note of run ``run_id``, this process (best effort: a read-only data folder skips it)."""
    if run_id is None:
        return
    note = _note(data_dir, run_id)
    try:
        note.parent.mkdir(parents=True, exist_ok=True)
        note.write_text(json.dumps({"pid": os.getpid(), "started": _started(os.getpid()),
                                    "host": socket.gethostname()}))
    except OSError:
        pass


def done_running(data_dir: Path, run_id: int | None) -> None:
    """Remove the note of a run that closed its own row."""
    if run_id is not None:
        _note(data_dir, run_id).unlink(missing_ok=True)


def close_interrupted_runs(session: Session, data_dir: Path) -> list[int]:
    """Close as ``interrupted`` every ``running`` row whose process is gone (see the module docstring);
    returns their ids. Does not commit."""
    closed = []
    for row in session.scalars(select(IngestRun).where(IngestRun.status == "running")):
        note = _note(data_dir, row.id)
        try:
            info = json.loads(note.read_text())
        except (OSError, ValueError):
            info = None
        if isinstance(info, dict) and isinstance(info.get("pid"), int):
            if info.get("host") != socket.gethostname() or _alive(info["pid"], info.get("started")):
                continue
        row.status = "interrupted"
        row.finished_at = row.finished_at or utcnow()
        closed.append(row.id)
        note.unlink(missing_ok=True)
    return closed
