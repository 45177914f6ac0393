"""Parent side of the bpy worker: a long-lived subprocess that renders many scenes or canonical renders.

:class:`BlenderWorker` starts ``python -P -m <WORKER_MODULE>`` (:mod:`mixcount.engine.worker_main`) lazily, sends one JSON request
per line and waits for the answer with a deadline. A worker that dies mid-scene (crash, OOM kill) or
overruns the per-scene timeout is killed (its whole process group) and the request raises
:class:`~mixcount.errors.RenderError`; the next request starts a fresh worker. The worker's stderr
(bpy and Cycles logging, and faulthandler's report of a crash) goes to a log file whose last lines are quoted
in errors: :class:`WorkerDied` carries the exit code (a signal as its negative number) and the log, which
is kept under its own name (``mixcount-<name>-<parent pid>-<worker pid>-<SIGNAL|exit N|timeout>.log``) so
that the next worker's log cannot wipe it.

Workers die with their run (docs/faults.md): each is started from one long-lived spawner thread of this
process, with ``MIXCOUNT_PARENT_PID`` set, so the worker's ``PR_SET_PDEATHSIG`` (Linux; set in
:mod:`mixcount.engine.worker_main`, which also watches its parent's pid) fires when this process dies,
not when the pool thread that asked for the worker ends.

A worker's imports never depend on the caller's folder (:func:`worker_command`): ``python -m`` alone puts
the current folder first on ``sys.path``, so a shell standing in a folder that holds a directory named
``mixcount`` (the folder a user cloned into) made every render fail with ``ModuleNotFoundError: No
module named 'mixcount.catalog.materials'``. The worker is started with ``-P`` (Python 3.11's safe path:
no current folder on the path) and the folder holding the parent's own ``mixcount`` package first on
``PYTHONPATH``, so it imports exactly the code of the process that started it, from any folder.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Iterator, Optional, Protocol

from mixcount.errors import RenderError
from mixcount.worker.canonical_contract import CanonicalRequest, CanonicalResult
from mixcount.worker.contract import MeshCacheRequest, MeshCacheResult, SceneRequest, SceneResult

STARTUP_TIMEOUT_S = 180.0
WORKER_MODULE = "mixcount.engine.worker_main"  # the entry module the worker process runs
PARENT_ENV = "MIXCOUNT_PARENT_PID"  # the pid the worker watches (it exits when that process is gone)
THREADS_ENV = "MIXCOUNT_WORKER_THREADS"  # the CPU threads its renders use: bpy's TBB is sized to it at import
TAIL_LINES = 20  # log lines a crash's error quotes
TAIL_CHARS = 3000


def package_root() -> str:
    """The folder holding the ``mixcount`` package this process runs (a checkout, or site-packages)."""
    return str(Path(__file__).resolve().parent.parent.parent)


def worker_command(python: str, module: str = WORKER_MODULE,
                   environ: Optional[dict[str, str]] = None) -> tuple[list[str], dict[str, str]]:
    """``(argv, env)`` that start ``module`` in ``python`` with imports that never depend on the current
    folder: ``-P`` keeps the folder off ``sys.path`` and :func:`package_root` leads ``PYTHONPATH`` (the
    parent's own package, also when it runs from a checkout that is not installed)."""
    env = dict(os.environ if environ is None else environ)
    root = package_root()
    rest = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != root]
    env["PYTHONPATH"] = os.pathsep.join([root, *rest])
    return [python, "-P", "-m", module], env


@contextlib.contextmanager
def in_package_root() -> Iterator[None]:
    """This process's current folder set to :func:`package_root` while the block runs, then back: Ray puts
    the driver's current folder FIRST on its workers' ``sys.path`` when ``ray.init`` runs, so a driver
    started in a folder holding a directory named ``mixcount`` had every scene actor import that one
    (seen with ray 2.x: ``mixcount.__file__`` of a remote task was the folder's). Wrap ``ray.init`` in it."""
    here = os.getcwd()
    os.chdir(package_root())
    try:
        yield
    finally:
        os.chdir(here)


class WorkerDied(RenderError):
    """A worker that died or was killed during a request: ``exit_code`` (negative: the signal; None: a
    timeout kill) and ``log``, the kept log of that worker's life (faulthandler's report included)."""

    def __init__(self, message: str, *, exit_code: Optional[int], log: Optional[Path]) -> None:
        super().__init__(message)
        self.exit_code = exit_code
        self.log = str(log) if log is not None else None


def exit_words(code: Optional[int]) -> str:
    """``SIGSEGV, exit code -11`` / ``exit code 3`` / ``exit code unknown``."""
    if code is None:
        return "exit code unknown"
    if code < 0:
        try:
            return f"{signal.Signals(-code).name}, exit code {code}"
        except ValueError:
            return f"signal {-code}, exit code {code}"
    return f"exit code {code}"


FAULT_HEADER = "Fatal Python error:"  # the first line of faulthandler's report
LINE_CHARS = 300  # a longer log line (faulthandler's "Extension modules: ..." list) is cut


def last_lines(text: str, n: int = TAIL_LINES, chars: int = TAIL_CHARS) -> str:
    """The last ``n`` non-empty lines of ``text``, at most ``chars`` characters; each line cut at
    :data:`LINE_CHARS`. When faulthandler's report began before those lines (its stacks of every thread
    run longer than ``n`` lines), the ``n`` lines from its header instead: what crashed, and where, is what
    a failure note must show."""
    lines = [ln.rstrip()[:LINE_CHARS] for ln in text.splitlines() if ln.strip()]
    start = max(0, len(lines) - n)
    crash = max((i for i, ln in enumerate(lines) if ln.startswith(FAULT_HEADER)), default=None)
    if crash is not None and crash < start:
        return "\n".join(lines[crash:crash + n])[:chars]
    return "\n".join(lines[start:])[-chars:]


class _Spawner:
    """One daemon thread that starts every worker process: ``PR_SET_PDEATHSIG`` signals a child when the
    THREAD that forked it ends, so the fork must come from a thread that lives as long as this process
    (a pool's or a look-ahead's thread ends long before its worker should)."""

    def __init__(self) -> None:
        self._jobs: "queue.Queue[tuple[Any, queue.Queue[Any]]]" = queue.Queue()
        self._lock = threading.Lock()
        self._thread: Optional[threading.Thread] = None
        self._pid = 0

    def _serve(self) -> None:
        while True:
            make, box = self._jobs.get()
            try:
                box.put((True, make()))
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                box.put((False, exc))

    def popen(self, make: Any) -> Any:
        with self._lock:
            if self._thread is None or not self._thread.is_alive() or self._pid != os.getpid():  # after a fork
                self._jobs, self._pid = queue.Queue(), os.getpid()
                self._thread = threading.Thread(target=self._serve, name="mixcount-worker-spawner", daemon=True)
                self._thread.start()
        box: "queue.Queue[Any]" = queue.Queue()
        self._jobs.put((make, box))
        ok, value = box.get()
        if not ok:
            raise value
        return value


_SPAWNER = _Spawner()


class BlenderWorker:
    """One bpy worker process (started on first use, restarted after a crash or a timeout)."""

    def __init__(self, *, name: str = "worker", log_dir: Optional[Path] = None,
                 python: str = sys.executable, startup_timeout: float = STARTUP_TIMEOUT_S, cpu_threads: int = 0) -> None:
        """``cpu_threads``: the Cycles threads this worker's requests render with, when the caller knows it
        (0: all cores). The worker imports bpy with TBB sized to it (``worker_main.import_bpy``): a worker
        of several on a machine must not keep a spinning TBB thread on every core (docs/blender.md)."""
        self.name = name
        self.cpu_threads = max(0, int(cpu_threads))
        self.python = python
        self.startup_timeout = startup_timeout
        self.log_dir = Path(log_dir) if log_dir else Path(tempfile.gettempdir())
        self.log_path = self.log_dir / f"mixcount-{name}-{os.getpid()}.log"
        self.proc: Optional[subprocess.Popen[bytes]] = None
        self._lines: "queue.Queue[Optional[str]]" = queue.Queue()
        self.restarts = 0
        self.starts = 0
        self.ready = False  # the worker answered its first line and serves requests
        self._log_kept = False  # this start's log was renamed (its worker died in a request)
        self.idle_deaths: list[str] = []  # workers that died between requests (exit, kept log)

    # -------------------------------------------------------------------------------- lifecycle

    @property
    def pid(self) -> Optional[int]:
        return self.proc.pid if self.proc is not None and self.proc.poll() is None else None

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self) -> None:
        if self.alive():
            return
        if self.proc is not None:
            self.restarts += 1
            code = self.proc.poll()
            if code and not self._log_kept:  # died between requests: its log is kept all the same
                self.idle_deaths.append(f"{exit_words(code)}; log kept as {self._keep_log(exit_words(code).split(',')[0])}")
        self._log_kept = False
        self.ready = False
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = open(self.log_path, "ab")  # O_APPEND: post() may truncate it under the running child
        log.truncate(0)  # this start's log (a crashed worker's was renamed and kept)
        args, env = worker_command(self.python, WORKER_MODULE)  # read now: tests swap the module
        env["PYTHONUNBUFFERED"] = "1"
        env["PYTHONFAULTHANDLER"] = "1"  # faulthandler from the interpreter's start (worker_main: all threads)
        env[PARENT_ENV] = str(os.getpid())
        env.pop(THREADS_ENV, None)  # never inherited from a parent that is itself a worker
        if self.cpu_threads:
            env[THREADS_ENV] = str(self.cpu_threads)
        try:
            self.proc = _SPAWNER.popen(lambda: subprocess.Popen(
                args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, env=env, start_new_session=True))
        finally:
            log.close()
        self.starts += 1
        self._lines = queue.Queue()
        threading.Thread(target=self._pump, args=(self.proc, self._lines), daemon=True).start()
        hello = self._read(self.startup_timeout, "starting")
        if not hello.get("ready"):
            self.kill()
            raise RenderError(f"{self.name}: unexpected first line from worker: {hello}")
        self.ready = True

    @staticmethod
    def _pump(proc: subprocess.Popen[bytes], lines: "queue.Queue[Optional[str]]") -> None:
        assert proc.stdout is not None
        for raw in proc.stdout:
            lines.put(raw.decode("utf-8", "replace"))
        lines.put(None)

    def kill(self) -> None:
        """Kill the worker's process group (no-op when it is not running)."""
        proc = self.proc
        if proc is None or proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            proc.kill()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # pragma: no cover
            pass

    def close(self) -> None:
        """Ask the worker to exit, kill it if it does not."""
        if self.alive():
            try:
                self._send({"op": "exit"})
                self._read(10.0, "exiting")
            except RenderError:
                pass
            try:
                assert self.proc is not None
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()

    def __enter__(self) -> "BlenderWorker":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -------------------------------------------------------------------------------- requests

    def log_tail(self, n: int = TAIL_CHARS, path: Optional[Path] = None) -> str:
        """The last lines of the worker's log (``path``: a kept one)."""
        try:
            with open(path or self.log_path, "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - 16 * n))  # room for a faulthandler report of many threads
                data = f.read()
        except OSError:
            return ""
        return last_lines(data.decode("utf-8", "replace"), chars=n)

    def _keep_log(self, why: str) -> Optional[Path]:
        """The dead worker's log renamed to ``<log>-<worker pid>-<why>.log`` (the next start writes a new
        one); the path it now has (the old one when the rename fails)."""
        pid = self.proc.pid if self.proc is not None else 0
        kept = self.log_path.with_name(f"{self.log_path.stem}-{pid}-{why.replace(' ', '')}.log")
        try:
            os.replace(self.log_path, kept)
        except OSError:
            return self.log_path if self.log_path.exists() else None
        return kept

    def _died(self, what: str, *, timeout: Optional[float] = None) -> WorkerDied:
        """The error of a worker gone during ``what`` (killed after ``timeout`` s, or died): its exit, the
        kept log and that log's last lines."""
        if timeout is not None:
            self.kill()
        code = None
        if self.proc is not None:
            try:
                code = self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:  # pragma: no cover
                self.kill()
        if timeout is not None:
            head, why = f"timed out after {timeout:.0f} s while {what}; worker killed", "timeout"
        else:
            head = f"worker died ({exit_words(code)}) while {what}"
            why = signal.Signals(-code).name if code is not None and code < 0 and -code in signal.valid_signals() \
                else f"exit{code}"
        log = self._keep_log(why)
        self._log_kept = True
        tail = self.log_tail(path=log) if log is not None else ""
        where = f"; its log is kept as {log}" if log is not None else ""
        return WorkerDied(f"{self.name}: {head}{where}; last lines:\n{tail or '(the log is empty)'}",
                          exit_code=None if timeout is not None else code, log=log)

    def _send(self, obj: dict[str, Any], what: str = "sending a request") -> None:
        assert self.proc is not None and self.proc.stdin is not None
        try:
            self.proc.stdin.write((json.dumps(obj) + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):  # the worker died between requests: say how
            raise self._died(what) from None

    def _read(self, timeout: float, what: str) -> dict[str, Any]:
        while True:
            try:
                line = self._lines.get(timeout=timeout)
            except queue.Empty:
                raise self._died(what, timeout=timeout) from None
            if line is None:
                raise self._died(what)
            line = line.strip()
            if not line:
                continue
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                continue  # stray output on the protocol channel: ignore

    def post(self, payload: dict[str, Any]) -> None:
        """Send one request without waiting (the worker started first); :meth:`answer` collects its answer.
        RenderError when the pipe is closed (the worker is killed)."""
        self.start()
        try:  # the log holds this worker's start and its last request (a crashed worker's is kept apart)
            self.log_path.write_bytes(b"")  # the child writes at its offset: truncating is safe
        except OSError:
            pass
        self._send(payload, f"handling {payload.get('op')!r}")

    def answer(self, timeout: float, what: str) -> dict[str, Any]:
        """The answer to the request :meth:`post` sent, within ``timeout`` seconds (RenderError naming
        ``what`` on a crash or overrun; the worker is then killed)."""
        return self._read(timeout, what)

    def request(self, payload: dict[str, Any], *, timeout: float) -> dict[str, Any]:
        """Send one request and wait up to ``timeout`` seconds for its answer."""
        self.post(payload)
        return self.answer(timeout, f"handling {payload.get('op')!r}")

    def _call(self, op: str, request: dict[str, Any], timeout: float, what: str) -> dict[str, Any]:
        """One typed operation: ``{"op", "request"}`` out, the answer's ``result`` back (RenderError on
        failure, crash or timeout)."""
        answer = self.request({"op": op, "request": request}, timeout=timeout)
        if not answer.get("ok"):
            tb = answer.get("traceback") or ""
            raise RenderError(f"{self.name}: {what} failed: {answer.get('error')}" + (f"\n{tb}" if tb else ""))
        result: dict[str, Any] = answer["result"]
        return result

    def run_scene_job(self, req: SceneRequest, *, timeout: float) -> SceneResult:
        """Run one scene; returns its SceneResult. Raises RenderError on failure, crash or timeout."""
        return SceneResult.from_dict(self._call(req.OP, req.to_dict(), timeout, "scene"))

    def render_canonical(self, req: CanonicalRequest, *, timeout: float) -> CanonicalResult:
        """Canonical renders of one object. Raises RenderError on failure, crash or timeout."""
        return CanonicalResult.from_dict(self._call(req.OP, req.to_dict(), timeout, "render"))

    def cache_meshes(self, req: MeshCacheRequest, *, timeout: float) -> MeshCacheResult:
        """Each asset's .blend mesh cache made now (a warm-up before timed scenes)."""
        return MeshCacheResult.from_dict(self._call(req.OP, req.to_dict(), timeout, "mesh cache"))


class Worker(Protocol):
    """What callers hold a bpy worker as: :class:`BlenderWorker` and
    :class:`~mixcount.worker.settle_ahead.SettleAheadWorker` both are one."""

    name: str

    @property
    def pid(self) -> Optional[int]: ...

    def alive(self) -> bool: ...

    def run_scene_job(self, req: SceneRequest, *, timeout: float) -> SceneResult: ...

    def render_canonical(self, req: CanonicalRequest, *, timeout: float) -> CanonicalResult: ...

    def cache_meshes(self, req: MeshCacheRequest, *, timeout: float) -> MeshCacheResult: ...

    def request(self, payload: dict[str, Any], *, timeout: float) -> dict[str, Any]: ...

    def kill(self) -> None: ...

    def close(self) -> None: ...
