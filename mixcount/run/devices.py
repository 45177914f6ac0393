"""``compose --device cpu|gpu|auto`` (``[compose] device``): which device the run's scenes render on,
decided once, before anything is written.

* ``cpu`` - nothing is probed (the tested default: no extra bpy process, no preference touched);
* ``gpu`` - one bpy worker subprocess is asked (the ``devices`` op, :mod:`mixcount.engine.devices`); when
  Cycles finds no CUDA / OptiX / HIP / oneAPI device the run stops with one line (RenderError, exit 2)
  and OUT is not made;
* ``auto`` - the same probe: a GPU when one works, else the CPU, said once (one note).

On Ray the driver's machine says nothing about the cluster's: :class:`~mixcount.run.ray_executor.RayExecutor`
resolves the device from the cluster's GPU resources instead and each actor reserves
``compose.ray_gpus_per_worker`` GPUs (docs/ray.md).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

from mixcount.errors import RenderError
from mixcount.worker.rerender_contract import DevicesRequest, DevicesResult

SETTING = "compose.device"
PROBE_TIMEOUT_S = 180.0


@dataclass(frozen=True)
class RunDevice:
    """The device the run's scene requests ask for ("cpu" / "gpu"), the probe's answer (None: not probed)
    and the line said once about it (None: nothing to say)."""

    device: str
    probed: Optional[DevicesResult]
    note: Optional[str]


def probe_in_worker(device: str) -> DevicesResult:
    """Ask a fresh bpy worker subprocess (logging to the temp folder, not OUT) what ``device`` gives."""
    from mixcount.worker.client import BlenderWorker

    with BlenderWorker(name="device-probe", log_dir=Path(tempfile.gettempdir())) as worker:
        answer = worker.request({"op": DevicesRequest.OP, "request": DevicesRequest(device, SETTING).to_dict()},
                                timeout=PROBE_TIMEOUT_S)
    if not answer.get("ok"):
        raise RenderError(f"the device check failed: {answer.get('error')}; nothing was written")
    return DevicesResult.from_dict(answer["result"])


def resolve_device(device: str, probe: Callable[[str], DevicesResult] = probe_in_worker) -> RunDevice:
    """``compose.device`` -> :class:`RunDevice` (see the module docstring); RenderError, one line, for a
    ``gpu`` that finds none."""
    if device == "cpu":
        return RunDevice("cpu", None, None)
    res = probe(device)
    if res.error:
        raise RenderError(f"{res.error}; nothing was written (use --device cpu or auto)")
    if res.used == "GPU":
        return RunDevice("gpu", res, f"rendering on the GPU: {res.backend} {', '.join(res.devices)}")
    found = ", ".join(res.found) or "nothing"
    return RunDevice("cpu", res, f"{SETTING} = \"auto\": no usable GPU (Cycles found {found}): rendering on the CPU")


def executor_device(executor: Any) -> Optional[RunDevice]:
    """The device an executor resolved itself (the Ray one: from its cluster's resources), or None."""
    resolved = getattr(executor, "device", None)
    if not isinstance(resolved, RunDevice):
        return None
    return resolved
