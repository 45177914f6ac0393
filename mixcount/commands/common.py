"""Shared CLI state: the resolved catalog URL and configuration for the current invocation.

The configuration is built once per invocation (:meth:`AppState.config`): default.toml, the global
``--config`` files, a command's own config file, the global ``--set`` overrides and then the command's
options that stand for config keys (``compose --samples`` = ``compose.samples``). After that it is frozen.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

import typer
from rich.console import Console

from mixcount.config import Config, load_config
from mixcount.errors import MixcountError
from mixcount.progress import PlainProgress

# Neither console reads emoji codes: ":x:" in a path or a name is printed as it is, never as an emoji.
# Results are plain text (no markup either: JSON, names and "[redacted]" markers are printed as they are);
# messages on stderr may style their own label, and quote user text with rich.markup.escape.
console = Console(stderr=True, soft_wrap=True, emoji=False)  # progress, warnings and messages
out = Console(highlight=False, soft_wrap=True, emoji=False, markup=False)  # results: summary, or --json JSON

# Help texts are plain text, not rich markup: rich would swallow "[default: split.seed]" as a style tag.
HELP_MARKUP = None


def result(summary: str | Iterable[str], data: Any, json_out: bool) -> None:
    """A command's result, the one convention of every command: stdout carries the readable ``summary``
    line(s), or with ``--json`` the JSON of ``data`` alone (one document a script can parse; the summary
    then goes to stderr, beside the progress and messages)."""
    lines = [summary] if isinstance(summary, str) else list(summary)
    if json_out:
        typer.echo(json.dumps(data, sort_keys=True, default=str))  # not rich: JSON could look like markup
    for line in lines:
        if line:
            (console if json_out else out).print(line, highlight=False, markup=False, soft_wrap=True)


def json_option(what: str = "the result") -> Any:
    """The ``--json`` option every command has (see :func:`result`)."""
    return typer.Option(False, "--json", help=f"Print {what} as JSON on stdout instead of a readable summary.")


class RichProgress:
    """A :class:`~mixcount.progress.ProgressReporter` that draws one rich bar on stderr."""

    def __init__(self, con: Console | None = None) -> None:
        self.console = con or console
        self._bar: Any = None
        self._task: Any = None
        # not a terminal (a pipe, a log file): a live bar draws nothing until the end, so plain lines instead
        self._plain = None if self.console.is_terminal else PlainProgress(self.console.file)

    def start(self, label: str, total: int) -> None:
        if self._plain is not None:
            return self._plain.start(label, total)
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
        if self._plain is not None:
            return self._plain.advance(n, info=info)
        if self._bar is not None:
            self._bar.update(self._task, advance=n, **({"info": info} if info is not None else {}))

    def update(self, *, completed: int | None = None, info: str | None = None) -> None:
        if self._plain is not None:
            return self._plain.update(completed=completed, info=info)
        if self._bar is not None:
            fields: dict[str, Any] = {} if info is None else {"info": info}
            if completed is not None:
                fields["completed"] = completed
            self._bar.update(self._task, **fields)

    def note(self, message: str) -> None:
        """A warning or note of a run, printed as plain text (no markup: it may quote paths and names)."""
        self.console.print(message, highlight=False, soft_wrap=True, markup=False, emoji=False)

    def stop(self) -> None:
        if self._plain is not None:
            return self._plain.stop()
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

    def catalog(self, *, create: bool = False):  # type: ignore[no-untyped-def]
        """The catalog of ``--db`` / ``MIXCOUNT_DB`` / ``catalog/catalog.db``. Only commands that add to a
        catalog (the ingest commands) pass ``create``: any other command on a SQLite file that does not
        exist stops with an error naming the path, instead of leaving an empty catalog behind."""
        from mixcount.catalog.db import open_catalog

        data_dir = self.config().catalog.data_dir  # a bad --config/--set is reported first
        if not create:
            require_existing_catalog(self.db)
        return open_catalog(self.db, data_dir=data_dir)


def check_catalog_file(db: str | None) -> None:
    """A CatalogError when ``db`` is an existing SQLite file that is not a usable catalog (read only)."""
    from mixcount.catalog.db import check_sqlite_file, head_revision, resolve_db_url, sqlite_file

    path = sqlite_file(resolve_db_url(db))
    if path is not None and path.is_file():
        check_sqlite_file(path, head_revision())


def require_existing_catalog(db: str | None) -> None:
    """A CatalogError when ``db`` resolves to a SQLite file that does not exist (other backends pass)."""
    import os

    from mixcount.catalog.db import resolve_db_url, sqlite_file
    from mixcount.errors import CatalogError

    path = sqlite_file(resolve_db_url(db))
    if path is None or path.exists():
        return
    given = ("--db" if db else "MIXCOUNT_DB") if (db or os.environ.get("MIXCOUNT_DB")) else "the default catalog/catalog.db"
    raise CatalogError(
        f"no catalog at {path} (from {given}): give --db PATH (or set MIXCOUNT_DB) for an existing catalog, "
        "or create one with `mixcount catalog ingest FOLDER`")


def state(ctx: typer.Context) -> AppState:
    root = ctx.find_root()
    if not isinstance(root.obj, AppState):
        root.obj = AppState()
    return root.obj
