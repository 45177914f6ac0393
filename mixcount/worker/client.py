"""Parent side of the bpy worker: a long-lived subprocess that renders many scenes or canonical renders.

:class:`BlenderWorker` starts ``python -m <WORKER_MODULE>`` (:mod:`mixcount.engine.worker_main`) lazily, sends one JSON request
per line and waits for the answer with a deadline. A worker that dies mid-scene (crash, OOM kill) or
overruns the per-scene timeout is killed (its whole process group) and the request raises
:class:`~mixcount.errors.RenderError`; the next request starts a fresh worker. The worker's stderr
(bpy and Cycles logging) goes to a log file whose tail is quoted in errors.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Optional, Protocol

from mixcount.errors import RenderError
from mixcount.worker.contract import (
    CanonicalRequest,
    CanonicalResult,
    MeshCacheRequest,
    MeshCacheResult,
    SceneRequest,
    SceneResult,
)

STARTUP_TIMEOUT_S = 180.0
WORKER_MODULE = "mixcount.engine.worker_main"  # the entry module the worker process runs


class BlenderWorker:
    """One bpy worker process (started on first use, restarted after a crash or a timeout)."""

    def __init__(self, *, name: str = "worker", log_dir: Optional[Path] = None,
                 python: str = sys.executable, startup_timeout: float = STARTUP_TIMEOUT_S) -> None:
        self.name = name
        self.python = python
        self.startup_timeout = startup_timeout
        self.log_dir = Path(log_dir) if log_dir else Path(tempfile.gettempdir())
        self.log_path = self.log_dir / f"mixcount-{name}-{os.getpid()}.log"
        self.proc: Optional[subprocess.Popen[bytes]] = None
        self._lines: "queue.Queue[Optional[str]]" = queue.Queue()
        self.restarts = 0
        self.starts = 0

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
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = open(self.log_path, "ab")
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        self.proc = subprocess.Popen(
            [self.python, "-m", WORKER_MODULE], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=log, env=env, start_new_session=True,
        )
        log.close()
        self.starts += 1
        self._lines = queue.Queue()
        threading.Thread(target=self._pump, args=(self.proc, self._lines), daemon=True).start()
        hello = self._read(self.startup_timeout, "starting")
        if not hello.get("ready"):
            self.kill()
            raise RenderError(f"{self.name}: unexpected first line from worker: {hello}")

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

    def log_tail(self, n: int = 2000) -> str:
        try:
            data = self.log_path.read_bytes()
        except OSError:
            return ""
        return data[-n:].decode("utf-8", "replace")

    def _send(self, obj: dict[str, Any]) -> None:
        assert self.proc is not None and self.proc.stdin is not None
        try:
            self.proc.stdin.write((json.dumps(obj) + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            self.kill()
            raise RenderError(f"{self.name}: worker pipe closed ({exc}); log tail:\n{self.log_tail()}") from None

    def _read(self, timeout: float, what: str) -> dict[str, Any]:
        while True:
            try:
                line = self._lines.get(timeout=timeout)
            except queue.Empty:
                self.kill()
                raise RenderError(f"{self.name}: timed out after {timeout:.0f} s while {what}; worker killed") from None
            if line is None:
                code = self.proc.wait() if self.proc is not None else None
                raise RenderError(f"{self.name}: worker died (exit code {code}) while {what}; log tail:\n"
                                  f"{self.log_tail()}")
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
        try:
            self.log_path.write_bytes(b"")  # O_APPEND in the child: truncating is safe
        except OSError:
            pass
        self._send(payload)

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
            raise RenderError(f"{self.name}: {what} failed: {answer.get('error')}\n{answer.get('traceback', '')}")
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
