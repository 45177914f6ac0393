"""One exception tree for mixcount: every error it raises on purpose is a :class:`MixcountError`.

Like httpx's own list, each class says when it is raised; catch the narrowest one you can handle::

    MixcountError               base of everything below; the CLI prints its message, exit code 2
    ├── ConfigError             unknown key, wrong type, unreadable config file
    ├── CatalogError            database unreachable / unwritable / another program's, missing object,
    │   │                       bad ingest path, unknown layout, unusable --metadata file
    │   ├── IngestError         one object could not be ingested (recorded as `broken`, batch goes on)
    │   └── CatalogBusyError    another process kept writing the catalog past catalog.writer_wait_s
    ├── CaptionError            a captioner could not caption one object (recorded, batch goes on)
    │   ├── CaptionRequestError an HTTP captioning request failed (``attempts``, ``retryable``)
    │   └── UnusableAnswerError a 200 answer that is not usable (malformed JSON, refusal): worth one repair
    ├── CompositionError        scene sampling / USD writing failed, bad compose options
    ├── RenderError             a Blender worker failed, timed out, died or answered nonsense
    ├── ExecutorError           the Ray cluster could not be reached or set up
    ├── StorageError            an output folder cannot take the run's files: no space, read-only, no permission
    ├── AssetError              a file a scene needs (model, texture, environment map) is missing or unreadable
    ├── DatasetError            a dataset's files do not match their record, or a scene cannot be merged
    │   └── PackageError        a dataset's assets cannot be packaged (a file missing everywhere looked)
    ├── ExportError             a dataset could not be exported (not a composed dataset, unknown split or
    │                           format, bad output folder)
    ├── EvaluationError         evaluation or statistics could not be computed from the given files
    │   ├── GroundTruthError    the ground-truth COCO file or dataset folder is missing or malformed
    │   └── PredictionError     the prediction file is missing or malformed
    ├── PartialFailure          a command over many items finished, but some (or all) items failed:
    │                           which, why (one line each), how to rerun only those (exit 3)
    └── StoppedByUser           Ctrl-C in a long run: what was finished and kept, how to go on (exit 130)

StorageError and AssetError stop a compose run: no other seed could succeed (docs/faults.md).
``RayExecutorError`` is the old name of ExecutorError (mixcount.run.ray_executor keeps it).

Only ``mixcount.cli`` turns these into messages and exit codes. The exit codes (docs/faults.md,
"Exit codes"): 0 everything done; 1 a check found problems (``verify``, ``merge`` leaving damaged scenes
out); 2 an error stopped the command (any other MixcountError, an OSError, a usage error); 3
:data:`EXIT_PARTIAL`, the command finished but items failed (:class:`PartialFailure`); 130 Ctrl-C.
"""

from __future__ import annotations


class MixcountError(Exception):
    """Base of every error mixcount raises on purpose."""


class ConfigError(MixcountError):
    """Configuration is invalid (unknown key, wrong type, unreadable file)."""


class CatalogError(MixcountError):
    """The catalog database or a catalog look-up failed."""


class IngestError(CatalogError):
    """One object could not be ingested; ``reason`` is stored as the object's error."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class CaptionError(MixcountError):
    """A captioner could not produce a valid caption set for one object."""


class CaptionRequestError(CaptionError):
    """Captioning one object failed; ``attempts`` = HTTP requests made, ``retryable`` = transient cause."""

    def __init__(self, message: str, *, attempts: int, retryable: bool = False) -> None:
        super().__init__(message)
        self.attempts = attempts
        self.retryable = retryable


class UnusableAnswerError(CaptionError):
    """A 200 answer that is not usable (malformed JSON, schema violation, refusal): worth one repair request.
    ``content`` is the answer text when there was one. The HTTP captioner catches it (mixcount.captions.http)."""

    def __init__(self, message: str, content: str | None) -> None:
        super().__init__(message)
        self.content = content


class CompositionError(MixcountError):
    """A scene could not be sampled or written."""


class RenderError(MixcountError):
    """A Blender worker failed, timed out or produced invalid output."""


class ExecutorError(MixcountError):
    """The Ray cluster could not be reached or set up."""


class StorageError(MixcountError):
    """An output folder cannot take the run's files (no space left, read-only, no permission): a fault
    that no other seed can fix, so a compose run stops on it."""


class AssetError(MixcountError):
    """A file a scene needs (an object's model, a floor texture, an environment map) is missing or
    unreadable: a compose run stops on it instead of drawing seed after seed."""


class DatasetError(MixcountError):
    """A dataset's files do not match their record (``mixcount verify``), or a scene cannot be merged."""


class PackageError(DatasetError):
    """A dataset's assets cannot be packaged (a file is missing everywhere it was looked for)."""


class ExportError(MixcountError):
    """A dataset could not be exported: not a composed dataset, unknown split or format, bad output folder."""


class EvaluationError(MixcountError):
    """Evaluation or statistics could not be computed from the given files."""


class GroundTruthError(EvaluationError):
    """The ground-truth COCO file (or dataset folder) is missing or malformed."""


class PredictionError(EvaluationError):
    """The prediction file is missing or malformed."""


class CatalogBusyError(CatalogError):
    """Another process held the catalog's writer lock (``<catalog>.writer``) for longer than
    ``catalog.writer_wait_s``; ``holder`` is what that process wrote in the lock file (pid, command, since)."""

    def __init__(self, message: str, holder: dict[str, object]) -> None:
        super().__init__(message)
        self.holder = holder


EXIT_PARTIAL = 3  # "finished, but some items failed": the exit code of PartialFailure


class PartialFailure(MixcountError):
    """A command that processes many items (objects to render or caption, scenes to compose) finished,
    but ``failed`` of its ``total`` items failed. ``failed`` holds one (label, reason) pair per item;
    ``rerun`` is the command line that redoes only those; ``log`` where the full errors are (worker
    tracebacks never reach the terminal); ``headline`` replaces the count line ("<what>: 2 of 9 failed"). The CLI prints one line per item, the count and the rerun line,
    and exits :data:`EXIT_PARTIAL`, also when every item failed: no failed item exits 0."""

    exit_code = EXIT_PARTIAL

    def __init__(self, what: str, failed: list[tuple[str, str]], total: int, *, rerun: str,
                 log: str | None = None, headline: str | None = None) -> None:
        count = len(failed)
        share = f"every one of {total}" if count >= total else f"{count} of {total}"
        super().__init__((headline or f"{what}: {share} failed") + (f" (full errors: {log})" if log else ""))
        self.what = what
        self.failed = failed
        self.total = total
        self.rerun = rerun
        self.log = log


class StoppedByUser(MixcountError):
    """Ctrl-C stopped a long run (compose): the message says what was finished and kept and how to go
    on; the CLI prints it and exits 130, the shell's code for an interrupt. Not a KeyboardInterrupt, so
    that the message reaches the CLI (typer turns a KeyboardInterrupt into a bare exit 130)."""


def one_line(text: str) -> str:
    """``text`` as one line of plain text: line breaks and other control characters written as escapes
    (``\\n``, ``\\x1b``), so a path holding a newline or a terminal escape cannot split or restyle an
    error line. Printable text, brackets and colons included, is kept as it is."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() or ch == " " else ascii(ch)[1:-1] for ch in text)


def os_error_line(exc: OSError) -> str:
    """One line for an OSError: its cause and the path it names (``No space left on device: /out/x``)."""
    cause = exc.strerror or str(exc) or type(exc).__name__
    path = exc.filename if exc.filename is not None else None
    return f"{cause}: {path}" if path is not None else cause
