"""Why a scene was thrown away (empty or rejected) - the rule and its figures, for ``scenes/.rejected/``.

The worker's :class:`~mixcount.worker.contract.SceneResult` of a scene it did not finish holds every
object's fate (status, drop reason, visibility, pixel counts, settled height) and its diagnostics. A
record that only said ``status: "empty"`` and listed every object "occluded" at visibility 0.0 left the
user guessing; :func:`rejection_reason` names the rule that decided and its numbers:

* ``empty`` - no counted object was kept: the counted objects' drop reasons, most common first, each with
  its figures: ``occluded`` (visibility range against the 1 - v_t needed, and how many had no pixel in view
  at all with their silhouette's size: a silhouette of 0 px means out of frame or behind the camera, a
  silhouette with 0 visible px means something covers it all), ``below_floor`` / ``flung_out`` /
  ``unstable`` (fell off or through: lowest settled heights), ``origin_outside_frame`` (where the origins
  projected in cam_0, against its frame);
* ``rejected`` - the final visibility re-check (the objects under 1 - v_t, with their values) or a count
  target that could not be met (``count_target`` verdict, target and kept per class).

``rule`` is the short key ``mixcount stats`` counts by (``empty: occluded``, ``rejected: recheck``, ...),
``why`` one readable line, ``figures`` the numbers. No bpy.
"""

from __future__ import annotations

from typing import Any, Sequence

from mixcount.worker.contract import STATUS_EMPTY, SceneResult

# drop reasons that mean a body left the floor or the physics (the fell-off family)
FELL = ("below_floor", "flung_out", "unstable")


def _rng(values: Sequence[float], fmt: str = "{:.2f}") -> str:
    if not values:
        return "n/a"
    lo, hi = min(values), max(values)
    return fmt.format(lo) if lo == hi else f"{fmt.format(lo)}-{fmt.format(hi)}"


def _outside(objs: list[Any], frame: tuple[int, int]) -> tuple[str, dict[str, Any]]:
    """``origin_outside_frame``: where the origins projected in cam_0 against its ``frame`` (width, height)."""
    n, (w, h) = len(objs), frame
    pts = [o.origin_px for o in objs if o.origin_px is not None and all(v == v for v in o.origin_px)]  # not NaN
    inside0 = sum(1 for x, y in pts if 0 <= x < w and 0 <= y < h)
    text = f"{n} origin outside the frame of a camera"
    if pts:
        text += (f" (cam_0 {w}x{h} px: origins at x {_rng([p[0] for p in pts], '{:.0f}')}, y "
                 f"{_rng([p[1] for p in pts], '{:.0f}')} px" + (f"; {inside0} inside cam_0, out of another camera's"
                                                               if inside0 else "") + ")")
    return text, {"objects": n, "frame_px": [w, h], "origin_px": [[round(x, 1), round(y, 1)] for x, y in pts],
                  "inside_cam_0": inside0}


def _figures(reason: str, objs: list[Any], need: float, frame: tuple[int, int]) -> tuple[str, dict[str, Any]]:
    """One reason's readable part and numbers over the counted objects it dropped."""
    n = len(objs)
    if reason == "origin_outside_frame":
        return _outside(objs, frame)
    if reason == "occluded":
        vis = [float(o.visibility or 0.0) for o in objs]
        unseen = [o for o in objs if not o.visible_px]
        sil = [int(o.unoccluded_px or 0) for o in unseen]
        out = sum(1 for s in sil if s == 0)
        text = f"{n} occluded (visibility {_rng(vis)}, {need:.2f} needed)"
        if unseen:
            text += (f"; {len(unseen)} with no pixel in view ({out} with no silhouette in the frame: out of frame or "
                     f"behind the camera; {len(unseen) - out} covered whole, silhouettes {_rng([s for s in sil if s], '{:.0f}')} px)")
        return text, {"objects": n, "visibility": sorted(round(v, 4) for v in vis), "visibility_needed": round(need, 4),
                      "no_pixel_in_view": len(unseen), "no_silhouette_in_frame": out}
    if reason in FELL:
        zs = [float(o.min_z) for o in objs if o.min_z is not None]
        text = f"{n} {reason.replace('_', ' ')} (lowest settled point {_rng(zs, '{:.2f}')} m)" if zs else f"{n} {reason.replace('_', ' ')}"
        return text, {"objects": n, "min_z_m": sorted(round(z, 4) for z in zs)}
    return f"{n} {reason.replace('_', ' ')}", {"objects": n}


def rejection_reason(result: SceneResult) -> dict[str, Any]:
    """``{"rule", "why", "figures"}`` of an empty or rejected scene (see the module docstring)."""
    need = 1.0 - float(result.visibility_threshold)
    frame = (int(result.camera.get("width") or 0), int(result.camera.get("height") or 0))
    counted = [o for o in result.objects if o.role == "counted"]
    if result.status == STATUS_EMPTY:
        dropped = [o for o in counted if not o.kept]
        by: dict[str, list[Any]] = {}
        for o in dropped:
            by.setdefault(o.reason or "unknown", []).append(o)
        order = sorted(by, key=lambda r: (-len(by[r]), r))
        parts, figures = [], {}
        for r in order:
            text, fig = _figures(r, by[r], need, frame)
            parts.append(text)
            figures[r] = fig
        fell = sum(len(by[r]) for r in FELL if r in by)
        main = "fell" if fell * 2 > len(dropped) else (order[0] if order else "no counted object")
        head = (f"all {len(dropped)} counted objects fell off or through the floor" if fell == len(dropped) and fell
                else f"no counted object kept: all {len(dropped)} dropped" if dropped else "no counted object in the scene")
        return {"rule": f"empty: {main}", "why": f"{head}: " + "; ".join(parts) if parts else head,
                "figures": {"counted": len(counted), "dropped_by_reason": {r: len(by[r]) for r in order}, **figures}}
    target = next((d for d in result.diagnostics if d.get("kind") == "count_target"), None)
    if target is not None and target.get("verdict") not in (None, "ok"):
        return {"rule": "rejected: count target",
                "why": f"count target not met ({target['verdict']}): {target.get('kept')} kept of {target.get('total')} "
                       f"asked, per class {target.get('per_class_kept')} against {target.get('per_class_target')}",
                "figures": {k: target.get(k) for k in ("verdict", "total", "kept", "per_class_target", "per_class_kept",
                                                       "topped_up", "reserve_unused")}}
    failing = next((d.get("objects", []) for d in result.diagnostics if d.get("kind") == "recheck_failed"), [])
    by_name = {o.name: o for o in result.objects}
    vis = {n: round(float(by_name[n].visibility or 0.0), 4) for n in failing if n in by_name}
    return {"rule": "rejected: recheck",
            "why": f"final visibility re-check: {len(failing)} kept object(s) below {need:.2f} visible "
                   f"({', '.join(f'{n} {v:.2f}' for n, v in vis.items()) or 'none named'})",
            "figures": {"visibility_needed": round(need, 4), "failing": vis}}


def object_lines(result: SceneResult) -> list[dict[str, Any]]:
    """Each counted object's fate and figures as the record keeps them."""
    keys = ("name", "status", "reason", "visibility", "visible_px", "unoccluded_px", "amodal_px", "min_z", "origin_px")
    return [{k: getattr(o, k) for k in keys} for o in result.objects if o.role == "counted"]
