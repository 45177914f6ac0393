"""SIGTERM stops a command the way Ctrl-C does.

``kill PID``, ``docker stop``, Slurm's time limit and systemd all send SIGTERM. Python's default for it is to
die at once: no ``finally`` runs, so a filter stopped after an hour kept only what its last periodic save
wrote, pools were not shut down, compose never said which scenes it had finished, and the exit status (-15)
said nothing of what was kept. Under ``--executor ray`` the driver behaved differently again, because
``ray.init`` installs its own SIGTERM handler (``sys.exit(15)``).

:func:`stop_on_sigterm` (the CLI's ``main`` holds it around every command) makes SIGTERM raise
:class:`KeyboardInterrupt` in the command's process, so each command's Ctrl-C path runs (compose's
"N scenes finished and kept", the filter's figure cache saved, pools shut down), and the CLI then exits
143 (128 + 15) with the same "stopped" line. :func:`keep_ours_over` puts the handler back after a library
(Ray) replaced it. A forked worker process that inherits the handler ends as SIGTERM's default does: the
stop belongs to the command, not to its workers.

A SIGINT that the parent set to be ignored stays ignored (``nohup``, and every background job of a
non-interactive shell: ``cmd &`` in a script starts with SIGINT ignored, so Ctrl-C and ``kill -INT`` do
nothing there, by POSIX, not by mixcount); such a run is stopped with SIGTERM.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from types import FrameType
from typing import Any, Iterator, Optional

SIGTERM_EXIT = 128 + int(signal.SIGTERM)  # 143: the shell's code for a process ended by SIGTERM


class _State:
    owner_pid: Optional[int] = None  # the process whose command a SIGTERM stops
    received: Optional[str] = None  # the name of the stop signal that arrived, if one did


def _on_sigterm(signum: int, frame: Optional[FrameType]) -> None:
    if os.getpid() != _State.owner_pid:  # a forked worker: SIGTERM's default, end now
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        return
    _State.received = "SIGTERM"
    raise KeyboardInterrupt("SIGTERM")


@contextlib.contextmanager
def stop_on_sigterm() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt in this process for the block (main thread only; a SIGTERM that the
    parent set to be ignored stays ignored). The previous handler is back afterwards."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
        yield
        return
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    owner, _State.owner_pid, _State.received = _State.owner_pid, os.getpid(), None
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        _State.owner_pid = owner


def stopped_by() -> Optional[str]:
    """``"SIGTERM"`` when the stop that ended the command was a SIGTERM, else None (Ctrl-C or none)."""
    return _State.received


@contextlib.contextmanager
def keep_ours_over() -> Iterator[None]:
    """Run a block that may install its own SIGTERM handler (``ray.init``) and put ours back after it,
    when ours was in place before."""
    before: Any = signal.getsignal(signal.SIGTERM)
    try:
        yield
    finally:
        if before is _on_sigterm and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, _on_sigterm)
