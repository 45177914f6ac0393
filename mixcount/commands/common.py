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
    command: str = "mixcount"  # the command being run ("mixcount catalog filter"), set by :func:`state`

    def rerun(self, *args: str, ctx: Any = None, drop: Sequence[str] = ()) -> str:
        """The command line that runs this invocation's command again with the same global options
        (``--db``, ``--config``, ``--set``), with ``ctx`` the options and arguments it was given (those of
        ``drop``, by parameter name, left out) and then ``args``: what a :class:`PartialFailure` says to
        rerun."""
        import shlex

        words = ["mixcount"] + (["--db", self.db] if self.db else [])
        words += [w for f in self.config_files for w in ("--config", str(f))]
        words += [w for o in self.overrides for w in ("--set", o)]
        words += self.command.split()[1:]
        if ctx is not None:
            words += given_options(ctx, drop)
        return shlex.join(words + list(args))

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

    def catalog(self, *, create: bool = False, write: bool = False):  # type: ignore[no-untyped-def]
        """The catalog of ``--db`` / ``MIXCOUNT_DB`` / ``catalog/catalog.db``. Only commands that add to a
        catalog (the ingest commands) pass ``create``: any other command on a SQLite file that does not
        exist stops with an error naming the path, instead of leaving an empty catalog behind.

        A command that writes the catalog passes ``write`` (``create`` implies it): it takes the catalog's
        writer lock (:class:`mixcount.catalog.db.Writer`), waiting up to ``catalog.writer_wait_s`` for another
        writer (said once on stderr), then stops with one line naming that process. Readers take no lock
        and never wait (SQLite WAL)."""
        from mixcount.catalog.db import Writer, open_catalog

        conf = self.config().catalog  # a bad --config/--set is reported first
        if not create:
            require_existing_catalog(self.db)
        writer = None
        if write or create:
            writer = Writer(command=self.command, wait_s=conf.writer_wait_s, on_wait=_say_waiting)
        return open_catalog(self.db, data_dir=conf.data_dir, writer=writer)


def given_options(ctx: Any, drop: Sequence[str] = ()) -> list[str]:
    """The options (those not at their default) and arguments of the command of ``ctx`` as words of a
    command line, in the order the command declares them; parameters named in ``drop`` left out."""
    words: list[str] = []
    for param in ctx.command.params:
        name = param.name
        if name in drop or name not in ctx.params:
            continue
        value = ctx.params[name]
        if param.param_type_name == "argument":
            words += [str(v) for v in (value if isinstance(value, (list, tuple)) else [value]) if v is not None]
            continue
        if value is None or value == param.default or (isinstance(value, (list, tuple)) and not value):
            continue
        if getattr(param, "is_flag", False):
            flag = param.opts[0] if value else (param.secondary_opts or [None])[0]
            words += [flag] if flag else []
        elif isinstance(value, (list, tuple)):
            words += [w for v in value for w in (param.opts[0], str(v))]
        else:
            words += [param.opts[0], str(value)]
    return words


def _say_waiting(line: str) -> None:
    """What a writer says once when another process holds the catalog's writer lock."""
    console.print(line, highlight=False, markup=False, soft_wrap=True, emoji=False)


def failure_log(catalog: Any, step: str, failures: Sequence[tuple[str, str]]) -> Path:
    """Append the full errors of a catalog step's failed items (worker tracebacks, log tails) to
    ``<data dir>/logs/<catalog>/<step>.log``, one block per run headed by its time, and return the path:
    the terminal gets one line per item (:class:`~mixcount.errors.PartialFailure`), the log the rest."""
    import datetime

    path: Path = Path(catalog.data_dir) / "logs" / str(catalog.files_key) / f"{step}.log"
    path.parent.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    with path.open("a", encoding="utf-8") as fh:
        fh.write(f"== {now} {step}: {len(failures)} failed\n")
        for label, error in failures:
            fh.write(f"-- {label}\n{error.rstrip()}\n")
    return path


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
    root.obj.command = ctx.command_path or root.obj.command
    return root.obj
