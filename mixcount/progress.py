"""How long work tells its caller how far it has got, without knowing who is watching.

The core (ingest, renders, captioning, compose) takes a :class:`ProgressReporter` and never imports the
CLI: the CLI passes one that draws a rich progress bar on stderr (``mixcount.commands.common``), or
:class:`PlainProgress` lines when stderr is not a terminal (a live bar would show nothing until the
end: ``catalog render`` into a log once stayed silent for minutes); a library caller passes nothing and
gets :class:`NullProgress`. ``note`` carries a one-line message a user
should see (a failed scene); a silent reporter sends it to :mod:`logging` instead.
"""

from __future__ import annotations

import logging
import time
from typing import Callable, Optional, Protocol, TextIO, runtime_checkable

log = logging.getLogger("mixcount")


@runtime_checkable
class ProgressReporter(Protocol):
    """Receives progress of one long job: ``start`` once, then ``advance``/``update``, then ``stop``."""

    def start(self, label: str, total: int) -> None: ...

    def advance(self, n: int = 1, *, info: Optional[str] = None) -> None: ...

    def update(self, *, completed: Optional[int] = None, info: Optional[str] = None) -> None: ...

    def note(self, message: str) -> None: ...

    def stop(self) -> None: ...


class NullProgress:
    """Draws nothing; notes go to the ``mixcount`` logger."""

    def start(self, label: str, total: int) -> None:
        return None

    def advance(self, n: int = 1, *, info: Optional[str] = None) -> None:
        return None

    def update(self, *, completed: Optional[int] = None, info: Optional[str] = None) -> None:
        return None

    def note(self, message: str) -> None:
        log.warning("%s", message)

    def stop(self) -> None:
        return None


PLAIN_INTERVAL_S = 10.0  # a plain progress line at most this often (and at the first step and the end)


def _clock_text(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class PlainProgress:
    """Progress as plain lines on a stream that is not a terminal (a log file, a pipe, CI): ``label:
    k/n (p %), elapsed, ETA, info`` at the first step, then at most every ``interval_s`` seconds, and when
    the job ends, where a live bar would draw nothing until the end. Notes are printed as they come."""

    def __init__(self, stream: TextIO, *, interval_s: float = PLAIN_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream, self.interval_s, self.clock = stream, interval_s, clock
        self.label, self.total, self.done, self.info = "", 0, 0, ""
        self._t0 = self._last = 0.0
        self._printed_at: int | None = None

    def start(self, label: str, total: int) -> None:
        self.label, self.total, self.done, self.info = label, int(total), 0, ""
        self._t0 = self.clock()
        self._last = self._t0 - self.interval_s
        self._printed_at = None

    def _line(self) -> str:
        elapsed = self.clock() - self._t0
        pct = f" ({100.0 * self.done / self.total:.0f} %)" if self.total else ""
        eta = (f", ETA {_clock_text(elapsed / self.done * (self.total - self.done))}"
               if self.done and self.total > self.done else "")
        info = f" {self.info}" if self.info else ""
        return f"{self.label}: {self.done}/{self.total}{pct}, elapsed {_clock_text(elapsed)}{eta}{info}"

    def _maybe_print(self, force: bool = False) -> None:
        now = self.clock()
        if force or now - self._last >= self.interval_s:
            self._last = now
            self._printed_at = self.done
            print(self._line(), file=self.stream, flush=True)

    def advance(self, n: int = 1, *, info: Optional[str] = None) -> None:
        self.done += n
        if info is not None:
            self.info = info
        self._maybe_print()

    def update(self, *, completed: Optional[int] = None, info: Optional[str] = None) -> None:
        if completed is not None:
            self.done = int(completed)
        if info is not None:
            self.info = info
        self._maybe_print()

    def note(self, message: str) -> None:
        print(message, file=self.stream, flush=True)

    def stop(self) -> None:
        if self.label and self._printed_at != self.done:
            self._maybe_print(force=True)
        self.label = ""


def as_reporter(progress: "ProgressReporter | bool | None") -> ProgressReporter:
    """``None``/``False``/``True`` (the old flag) give a :class:`NullProgress`; a reporter is returned as is."""
    if isinstance(progress, bool) or progress is None:
        return NullProgress()
    return progress
