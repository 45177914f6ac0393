"""Shared CLI state: the resolved catalog URL and configuration for the current invocation.

The configuration is built once per invocation (:meth:`AppState.config`): default.toml, the global
``--config`` files, a command's own config file, the global ``--set`` overrides and then the command's
options that stand for config keys (``compose --samples`` = ``compose.samples``). After that it is frozen.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import typer
from rich.console import Console

from mixcount.config import Config, load_config
from mixcount.errors import MixcountError

console = Console(stderr=True, soft_wrap=True)  # progress and summaries; JSON goes to stdout only
out = Console(highlight=False, soft_wrap=True)


class RichProgress:
    """A :class:`~mixcount.progress.ProgressReporter` that draws one rich bar on stderr."""

    def __init__(self, con: Console | None = None) -> None:
        self.console = con or console
        self._bar: Any = None
        self._task: Any = None

    def start(self, label: str, total: int) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

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

    def config(self, *, files: Sequence[Path] = (), values: Optional[Mapping[str, Any]] = None) -> Config:
        """The invocation's configuration, built on the first call and then fixed.

        ``files`` (a command's own ``--config``) and ``values`` (dotted key -> value, from command options
        that stand for config keys; None values are left out) apply on that first call only.
        """
        values = {k: v for k, v in (values or {}).items() if v is not None}
        if self._config is None:
            self._config = load_config([*self.config_files, *files], self.overrides, values=values)
        elif files or values:
            raise MixcountError("internal: command config options must be given on the first config() call")
        return self._config

    def catalog(self):  # type: ignore[no-untyped-def]
        from mixcount.catalog.db import open_catalog

        return open_catalog(self.db, data_dir=self.config().catalog.data_dir)


def state(ctx: typer.Context) -> AppState:
    root = ctx.find_root()
    if not isinstance(root.obj, AppState):
        root.obj = AppState()
    return root.obj
