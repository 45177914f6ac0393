"""Shared CLI state: the resolved catalog URL and configuration for the current invocation."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from mixcount.config import Config, load_config

console = Console(stderr=True, soft_wrap=True)  # progress and summaries; JSON goes to stdout only
out = Console(highlight=False, soft_wrap=True)


class RichProgress:
    """A :class:`~mixcount.progress.ProgressReporter` that draws one rich bar on stderr."""

    def __init__(self, con: Console | None = None) -> None:
        self.console = con or console
        self._bar: Any = None
        self._task: Any = None

    def start(self, label: str, total: int) -> None:
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                   TimeRemainingColumn)

        self._bar = Progress(TextColumn(f"[bold]{label}[/]"), BarColumn(), MofNCompleteColumn(),
                             TextColumn("{task.fields[info]}"), TimeElapsedColumn(), TextColumn("ETA"),
                             TimeRemainingColumn(), console=self.console, transient=False)
        self._task = self._bar.add_task(label, total=total, info="")
        self._bar.start()

    def advance(self, n: int = 1, *, info: str | None = None) -> None:
        if self._bar is not None:
            self._bar.update(self._task, advance=n, **({"info": info} if info is not None else {}))

    def update(self, *, completed: int | None = None, info: str | None = None) -> None:
        if self._bar is not None:
            fields: dict[str, Any] = {} if info is None else {"info": info}
            if completed is not None:
                fields["completed"] = completed
            self._bar.update(self._task, **fields)

    def note(self, message: str) -> None:
        self.console.print(message, highlight=False, soft_wrap=True)

    def stop(self) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None


@dataclass
class AppState:
    db: str | None = None
    config_files: list[Path] = field(default_factory=list)
    overrides: list[str] = field(default_factory=list)
    _config: Config | None = None

    def config(self) -> Config:
        if self._config is None:
            self._config = load_config(self.config_files, self.overrides)
        return self._config

    def catalog(self):  # type: ignore[no-untyped-def]
        from mixcount.catalog.db import open_catalog

        return open_catalog(self.db, data_dir=self.config()["catalog"]["data_dir"])


def state(ctx: typer.Context) -> AppState:
    root = ctx.find_root()
    if not isinstance(root.obj, AppState):
        root.obj = AppState()
    return root.obj
