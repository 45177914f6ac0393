"""Shared CLI state: the resolved catalog URL and configuration for the current invocation."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import typer
from rich.console import Console

from mixcount.config import Config, load_config

console = Console(stderr=True, soft_wrap=True)  # progress and summaries; JSON goes to stdout only
out = Console(highlight=False, soft_wrap=True)


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
