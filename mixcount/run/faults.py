"""Faults that no other seed can fix, told apart from a bad scene (no bpy).

A compose run regenerates a scene that came out empty, failed its visibility re-check or errored: a
new seed may well succeed. Three faults are different, and a run that went on drawing seeds for them
would only pile up failures (and tracebacks) for the same cause:

* the output folder (or the converted-asset cache) cannot take the files: no space left, a quota,
  a read-only file system, no permission;
* a file a scene needs is missing or unreadable: an object's model (when no converted copy is
  cached), the container's collision mesh, a floor texture, an environment map;

:func:`check_output` probes a folder by writing a small file (and, when asked, compares its free space
with what a scene needs); :func:`classify_failure` looks at a failed scene's error text for the errno of
such a fault and probes the output folder, because the worker does not always see an errno (a full disk
showed up as ``_ids.exr lacks passes``: Blender writes its passes without raising);
:func:`missing_inputs` checks a scene's input files before it is rendered. Each returns one line naming
the path and the cause, or None.
"""

from __future__ import annotations

import errno
import os
import re
import uuid
from pathlib import Path
from typing import Any, Iterable, Optional

STORAGE_ERRNOS = {errno.ENOSPC: "no space left on device", errno.EDQUOT: "disk quota exceeded",
                  errno.EROFS: "read-only file system", errno.EACCES: "permission denied",
                  errno.EPERM: "operation not permitted"}
ALWAYS_FATAL = {errno.ENOSPC, errno.EDQUOT, errno.EROFS}  # wherever they happen, no seed avoids them
PROBE_BYTES = 64 * 1024
BYTES_PER_PIXEL = 64  # a scene's peak on disk while it renders: passes, EXR intermediates, crops
SCENE_OVERHEAD_BYTES = 1 << 20
_ERRNO_RE = re.compile(r"\[Errno (\d+)\][^:'\"]*(?::\s*'([^']*)')?")
_TEXT_ERRNOS = {"No space left on device": errno.ENOSPC, "Disk quota exceeded": errno.EDQUOT,
                "Read-only file system": errno.EROFS}


def human_bytes(n: float) -> str:
    for unit in ("bytes", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"  # pragma: no cover


def scene_bytes_needed(resolution: int, largest_scene: int = 0) -> int:
    """About how many bytes one scene needs free while it renders (its temporary folder at its peak)."""
    return max(int(resolution) ** 2 * BYTES_PER_PIXEL + SCENE_OVERHEAD_BYTES, 2 * int(largest_scene))


def free_bytes(folder: Path) -> Optional[int]:
    try:
        st = os.statvfs(folder)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def storage_line(code: int, path: Path | str, detail: str = "") -> str:
    cause = STORAGE_ERRNOS.get(code) or os.strerror(code).lower()
    return f"{cause}: {path}" + (f" ({detail})" if detail else "")


def check_output(folder: Path, *, need_bytes: int = 0) -> Optional[str]:
    """None when ``folder`` takes a new file; else one line (cause and path). With ``need_bytes``, a
    folder with less free space than that counts as full."""
    folder = Path(folder)
    probe = folder / f".probe-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:  # the folder's times are put back after the probe: compose reads "a scene appeared" off its mtime
        before = folder.stat()
    except OSError:
        before = None
    try:
        with open(probe, "wb") as fh:
            fh.write(b"\0" * min(PROBE_BYTES, max(need_bytes, 1)))
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        code = exc.errno or errno.EIO
        free = free_bytes(folder)
        detail = f"{human_bytes(free)} free" if code == errno.ENOSPC and free is not None else ""
        return storage_line(code, folder, detail) if code in STORAGE_ERRNOS else f"cannot write in {folder}: {exc}"
    finally:
        try:
            probe.unlink()
            if before is not None:
                os.utime(folder, ns=(before.st_atime_ns, before.st_mtime_ns))
        except OSError:
            pass
    free = free_bytes(folder)
    if need_bytes and free is not None and free < need_bytes:
        return storage_line(errno.ENOSPC, folder,
                            f"{human_bytes(free)} free, a scene needs about {human_bytes(need_bytes)}")
    return None


def errors_in_text(text: str) -> list[tuple[int, Optional[str]]]:
    """(errno, path or None) of every storage error an error text names (``[Errno 28] ...: '/out/x'`` or
    the bare message, as bpy and the worker print it)."""
    found: list[tuple[int, Optional[str]]] = []
    for m in _ERRNO_RE.finditer(text or ""):
        code = int(m.group(1))
        if code in STORAGE_ERRNOS:
            found.append((code, m.group(2)))
    if not found:
        for message, code in _TEXT_ERRNOS.items():
            if message.lower() in (text or "").lower():
                found.append((code, None))
    return found


def _under(path: str, roots: Iterable[Path]) -> bool:
    p = os.path.abspath(path)
    return any(p == str(r) or p.startswith(str(r).rstrip(os.sep) + os.sep) for r in roots)


def classify_failure(error: Optional[str], *, out_dir: Path, assets_dir: Path, need_bytes: int) -> Optional[str]:
    """One line when a failed scene's error is a storage fault no other seed can fix, else None.

    Fatal: an errno of no space / quota / read-only anywhere; permission denied on a path under the
    output folder or the asset cache; or, whatever the text says, an output folder that no longer takes
    a scene (a probe file cannot be written, or less than ``need_bytes`` is free)."""
    out_dir, assets_dir = Path(out_dir).resolve(), Path(assets_dir).resolve()
    for code, path in errors_in_text(error or ""):
        if code in ALWAYS_FATAL or (path is not None and _under(path, (out_dir, assets_dir))):
            where = path or out_dir
            free = free_bytes(Path(path).parent if path else out_dir)
            detail = f"{human_bytes(free)} free" if code == errno.ENOSPC and free is not None else ""
            return storage_line(code, where, detail)
    for folder in (out_dir / "scenes", out_dir):
        if folder.is_dir():
            return check_output(folder, need_bytes=need_bytes)
    return None


def _readable(path: Path) -> Optional[str]:
    """None when ``path`` is a file that can be read, else why not."""
    try:
        with open(path, "rb") as fh:
            fh.read(1)
    except FileNotFoundError:
        return "missing"
    except IsADirectoryError:
        return "a folder, not a file"
    except OSError as exc:
        return f"unreadable: {exc.strerror}"
    return None


def missing_inputs(spec: Any, assets_dir: Path) -> Optional[str]:
    """One line naming the first input file of ``spec`` (a SceneSpec) that is missing or unreadable:
    an asset's model (unless its converted copy is cached in ``assets_dir``), the container's collision
    mesh, a floor texture, an environment map. None when all can be read."""
    from mixcount.usd.assets import asset_key

    container_id = spec.container.object_id if spec.container is not None else None
    for a in spec.assets:
        cached = (Path(assets_dir) / f"{asset_key(a.content_hash, str(a.model_path), a.source_units)}.usdc").is_file()
        why = None if cached else _readable(Path(a.model_path))
        if why:
            return f"model of object {a.object_id} ({a.name}) is {why}: {a.model_path}"
        if a.object_id == container_id and a.collision_path:
            why = _readable(Path(a.collision_path))
            if why:
                return f"collision mesh of container {a.object_id} ({a.name}) is {why}: {a.collision_path}"
    for name, path in sorted((spec.floor.material.maps or {}).items()):
        why = _readable(Path(path))
        if why:
            return f"{name} texture of floor material {spec.floor.material.name!r} is {why}: {path}"
    env = spec.environment
    if env.kind == "hdri" and env.path:
        why = _readable(Path(env.path))
        if why:
            return f"environment map is {why}: {env.path}"
    return None


def failure_cause(error: Optional[str], exit_code: Optional[int] = None) -> str:
    """A failed scene's cause in a few words, for counting (``mixcount stats``): ``worker SIGSEGV`` (a worker
    killed by a signal), ``worker exit 3``, ``timeout``, ``storage`` (a full / read-only disk), ``sampling``,
    ``scene error: <ExceptionType>`` (a Python error in the worker, which lived on) or ``error: <Type>``."""
    import signal as _signal

    text = error or ""
    if exit_code is not None and exit_code < 0:
        try:
            return f"worker {_signal.Signals(-exit_code).name}"
        except ValueError:
            return f"worker signal {-exit_code}"
    if exit_code is not None:
        return f"worker exit {exit_code}"
    if "timed out after" in text:
        return "timeout"
    if any(code in STORAGE_ERRNOS for code, _ in errors_in_text(text)) or any(t in text for t in _TEXT_ERRNOS):
        return "storage"
    if text.startswith("sampling:"):
        return "sampling"
    m = re.search(r"scene failed: (\w+):", text)
    if m:
        return f"scene error: {m.group(1)}"
    m = re.match(r"(\w+):", text)
    return f"error: {m.group(1)}" if m else "unknown"
