"""Where Cycles renders a compose scene (bpy): ``compose.device`` = cpu | gpu | auto.

:func:`select` enables the devices of the first GPU backend of :data:`GPU_BACKENDS` that has one, through
Cycles' add-on preferences (``compute_device_type`` and each device's ``use``), or the CPU. The worker
process remembers the device its requests ask for (:func:`use`, called per ``scene`` request by
:mod:`mixcount.engine.worker_main`), and :func:`apply` - called where the render settings are made
(:func:`mixcount.engine.render_passes.configure_common`) - sets ``scene.cycles.device`` and re-enables the
devices each time, because a factory-settings reset between scenes resets the preferences too.

``cpu`` never touches the preferences: the tested default stays exactly as it was. ``gpu`` with no GPU is an
``error`` line (the parent probes once with the ``devices`` op and stops before anything is written);
``auto`` falls back to the CPU. Verified here on CPU-only machines (no CUDA / OptiX device): see
docs/faults.md, "Devices".
"""

from __future__ import annotations

from typing import Any, Optional

from mixcount.scene_config import DEVICES
from mixcount.worker.rerender_contract import DevicesResult

GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI")  # tried in this order; the first with a device is used

_current = "cpu"  # what this process's scene requests asked for last


def _cpu(scene: Any) -> DevicesResult:
    if scene is not None:
        scene.cycles.device = "CPU"
    return DevicesResult(used="CPU", backend="NONE", devices=(), found=(), error="")


def select(device: str, scene: Any = None, *, key: str = "compose.device") -> DevicesResult:
    """Cycles' devices for ``device`` (see the module docstring); with ``scene`` the choice is applied.
    ``key`` names the setting in the error line of a ``gpu`` that finds none."""
    import bpy

    if device not in DEVICES:
        raise ValueError(f"{key} must be one of {', '.join(DEVICES)}, got {device!r}")
    if device == "cpu":
        return _cpu(scene)
    prefs = bpy.context.preferences.addons["cycles"].preferences
    found: list[str] = []
    chosen, gpus = "", []
    for backend in GPU_BACKENDS:
        try:
            prefs.compute_device_type = backend
        except TypeError:  # this Blender build has no such backend
            continue
        have = [d for d in prefs.get_devices_for_type(backend) if d.type == backend]
        found.extend(f"{d.type}: {d.name}" for d in have)
        if have and not chosen:
            chosen, gpus = backend, have
    if not chosen:
        prefs.compute_device_type = "NONE"
        found.extend(f"{d.type}: {d.name}" for d in prefs.get_devices_for_type("CPU"))
        if device == "gpu":
            return DevicesResult(used="", backend="", devices=(), found=tuple(found),
                                 error=f"{key} = \"gpu\" but Cycles found no usable GPU (tried "
                                       f"{', '.join(GPU_BACKENDS)}; found {', '.join(found) or 'nothing'})")
        _cpu(scene)
        return DevicesResult(used="CPU", backend="NONE", devices=(), found=tuple(found), error="")
    prefs.compute_device_type = chosen
    for d in prefs.devices:
        d.use = d in gpus
    if scene is not None:
        scene.cycles.device = "GPU"
    return DevicesResult(used="GPU", backend=chosen, devices=tuple(f"{d.type}: {d.name}" for d in gpus),
                         found=tuple(found), error="")


def use(device: Optional[str], *, key: str = "compose.device") -> DevicesResult:
    """Remember ``device`` (None: the CPU) for this process's next scenes; the selection it gives (no scene
    applied). A ``gpu`` without one raises RuntimeError with the error line (the scene fails, the worker lives)."""
    global _current
    res = select(device or "cpu", key=key)
    if res.error:
        raise RuntimeError(res.error)
    _current = device or "cpu"
    return res


def apply(scene: Any) -> DevicesResult:
    """Set ``scene``'s Cycles device to what :func:`use` chose (the CPU when nothing was asked)."""
    return select(_current, scene)
