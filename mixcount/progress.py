"""How long work tells its caller how far it has got, without knowing who is watching.

The core (ingest, renders, captioning, compose) takes a :class:`ProgressReporter` and never imports the
CLI: the CLI passes one that draws a rich progress bar on stderr (``mixcount.commands.common``), a
library caller passes nothing and gets :class:`NullProgress`. ``note`` carries a one-line message a user
should see (a failed scene); a silent reporter sends it to :mod:`logging` instead.
"""

from __future__ import annotations

import logging
from typing import Optional, Protocol, runtime_checkable

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


def as_reporter(progress: "ProgressReporter | bool | None") -> ProgressReporter:
    """``None``/``False``/``True`` (the old flag) give a :class:`NullProgress`; a reporter is returned as is."""
    if isinstance(progress, bool) or progress is None:
        return NullProgress()
    return progress
