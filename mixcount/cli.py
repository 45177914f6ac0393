"""The `mixcount` command line. The only place that turns errors into messages and exit codes."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer

from mixcount.commands.common import HELP_MARKUP, AppState, console
from mixcount.errors import MixcountError, PartialFailure, StoppedByUser, one_line, os_error_line

app = typer.Typer(
    name="mixcount",
    help="Photorealistic mixed-object counting datasets from a catalog of real 3D object captures.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=HELP_MARKUP,
)
catalog_app = typer.Typer(
    help="Ingest, curate, caption and split the asset catalog.", no_args_is_help=True, rich_markup_mode=HELP_MARKUP
)
app.add_typer(catalog_app, name="catalog")


def _print_version(value: bool) -> None:
    if value:
        from mixcount import __version__

        typer.echo(f"mixcount {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    ctx: typer.Context,
    db: Optional[str] = typer.Option(
        None, "--db", envvar="MIXCOUNT_DB", help="Catalog database: a path or SQLAlchemy URL [default: catalog/catalog.db]."
    ),
    config: list[Path] = typer.Option(
        [], "--config", "-c", help="Config file(s) layered over configs/default.toml: a path, or the name of a bundled config "
             "(quick = small sizes, counts and samples for trials); repeatable."
    ),
    set_: list[str] = typer.Option(
        [], "--set", help="Override one config key, e.g. --set scene.n_objects=[30,60] or --set compose.samples=16; repeatable "
             "(an unknown key is an error that names the nearest known one)."
    ),
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the mixcount version and exit."
    ),
) -> None:
    ctx.obj = AppState(db=db, config_files=list(config), overrides=list(set_))


def _register_commands() -> None:
    import importlib

    for name in ("ingest", "curate", "captions", "compose", "render", "evaluate", "demo", "export", "verify", "package"):
        try:
            module = importlib.import_module(f"mixcount.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"mixcount.commands.{name}":
                continue
            raise
        module.register(app, catalog_app)


_register_commands()


def print_error(message: str, *, label: str = "error:") -> None:  # label "": the message alone
    """One error line on stderr: a red ``label``, then ``message`` as plain text. Neither rich markup nor
    emoji codes are read in the message (``reviews/[red]secret[/red]:x:.json`` is printed as it is) and
    control characters are escaped (:func:`mixcount.errors.one_line`), so the line says what it was given."""
    from rich.text import Text

    line = Text(label, style="bold red")
    line.append((" " if label else "") + one_line(str(message)))
    console.print(line, highlight=False, soft_wrap=True, emoji=False, markup=False)


FAILED_LINES = 50  # per-item lines of a PartialFailure printed; the log holds every one


def first_line(text: str, limit: int = 200) -> str:
    """The first non-empty line of ``text``, cut at ``limit`` characters: a worker's traceback or log tail
    stays in the log file, the terminal gets what failed."""
    line = next((ln.strip() for ln in str(text).splitlines() if ln.strip()), "")
    return line if len(line) <= limit else line[: limit - 3] + "..."


def print_partial(exc: PartialFailure) -> None:
    """A :class:`PartialFailure`: one line per failed item (at most :data:`FAILED_LINES`), the count, and
    the line that reruns only those."""
    for label, reason in exc.failed[:FAILED_LINES]:
        print_error(f"{label}: {first_line(reason)}", label="failed:")
    if len(exc.failed) > FAILED_LINES:
        print_error(f"... and {len(exc.failed) - FAILED_LINES} more" + (f" (every one in {exc.log})" if exc.log else ""),
                    label="failed:")
    print_error(str(exc))
    print_error(exc.rerun, label="rerun only those:")


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point. Exit codes (docs/faults.md, "Exit codes"): 0 everything done; 1 a check
    found problems (``verify``; ``merge`` leaving damaged scenes out); 2 an error stopped the command:
    usage errors (the usage line and one line of error), a :class:`MixcountError` (its message), an
    ``OSError`` (cause and path, one line); 3 the command finished but items failed
    (:class:`PartialFailure`: one line per failed item, the count, how to rerun only those; also when every
    item failed); 130 Ctrl-C and 143 SIGTERM (:mod:`mixcount.stop_signals`), with one line
    (:class:`StoppedByUser`: what a run kept and how to go on).
    Never a traceback for any of them; every message is printed as plain text (:func:`print_error`)."""
    from mixcount.stop_signals import stop_on_sigterm

    with stop_on_sigterm():  # SIGTERM (kill, docker stop, Slurm) stops a command as Ctrl-C does
        return _run(argv)


def _stop_code(message: str) -> int:
    """Print a stop's line and give its exit code: 130 for Ctrl-C, 143 for SIGTERM (mixcount.stop_signals)."""
    from mixcount.stop_signals import SIGTERM_EXIT, stopped_by

    if stopped_by() == "SIGTERM":
        print_error(message.replace("stopped by the user", "stopped by SIGTERM"), label="")
        return SIGTERM_EXIT
    print_error(message, label="")
    return 130


def _run(argv: list[str] | None) -> int:
    """The command, its errors turned into lines and exit codes (:func:`main`'s table)."""
    # typer vendors click as ``typer._click``: its exceptions are not ``click.exceptions`` classes.
    from typer._click import exceptions as click_exc

    try:
        result = app(args=argv, standalone_mode=False, prog_name="mixcount")
    except StoppedByUser as exc:
        return _stop_code(str(exc))
    except PartialFailure as exc:
        print_partial(exc)
        return exc.exit_code
    except MixcountError as exc:
        print_error(str(exc))
        return 2
    except OSError as exc:  # a disk or permission fault no command turned into its own message: one line
        print_error(os_error_line(exc))
        return 2
    except (KeyboardInterrupt, typer.Abort):
        return _stop_code("stopped by the user")
    except click_exc.ClickException as exc:  # usage errors: bad option, bad value, unknown command
        exc.show()
        return int(exc.exit_code)
    except SystemExit as exc:  # typer's own exits (--help)
        return int(exc.code or 0)
    # In non-standalone mode typer returns the code of typer.Exit(n), and 130 for a Ctrl-C that it caught
    # as a KeyboardInterrupt (a command with more to say raises StoppedByUser instead).
    if isinstance(result, int) and not isinstance(result, bool) and result:
        if result == 130:
            return _stop_code("stopped by the user")
        return result
    return 0


if __name__ == "__main__":
    sys.exit(main())
