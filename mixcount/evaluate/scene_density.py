"""Scene density: what a scene kept of what it spawned, read from its ``metadata.json``.

Every spawned counted object and distractor is listed in ``metadata["objects"]`` with ``role``
(counted | distractor), ``status`` (kept | dropped) and, when dropped, ``reason`` (below_floor,
flung_out, unstable, interpenetration, origin_outside_frame, occluded). :func:`scene_density` turns one
scene's metadata into spawned / kept counts, drop reasons and the counted classes that ended with no
visible instance; :func:`summarise_density` pools many scenes (retention, means per scene, container vs
no-container scenes, the share of bodies lost off the floor).

Standard library only, on purpose: ``bench/density.py`` loads this file from its own checkout by path,
so the figures of a *before* run (scenes made by an older mixcount on ``PYTHONPATH``) are computed by
the same code as those of the *after* run.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Iterable, Mapping, Optional

KEPT = "kept"
LOST_OFF_FLOOR = ("below_floor", "flung_out")  # the settle checks' "off / under the floor" verdicts


def _reasons(objects: Iterable[Mapping[str, Any]]) -> dict[str, int]:
    c = Counter(str(o.get("reason") or "unknown") for o in objects if o["status"] != KEPT)
    return dict(sorted(c.items()))


def classes_without_instances(meta: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The scene's counted classes none of whose instances was kept, each as ``{"class_index",
    "category_id", "name", "spawned", "reasons": {reason: count}}``.

    The scene writer's own ``classes_without_instances`` key is used when present; older scenes get the
    same list computed from ``objects`` and ``spec.classes``."""
    if "classes_without_instances" in meta:
        return [dict(c) for c in meta["classes_without_instances"]]
    names = {int(c["id"]): str(c["name"]) for c in meta["categories"]}
    by_class: dict[int, list[Mapping[str, Any]]] = {}
    for o in meta["objects"]:
        if o["role"] == "counted":
            by_class.setdefault(int(o["class_index"]), []).append(o)
    out = []
    for c in meta["spec"]["classes"]:
        ci = int(c["class_index"])
        objs = by_class.get(ci, [])
        if any(o["status"] == KEPT for o in objs):
            continue
        cid: Optional[int] = int(objs[0]["category_id"]) if objs else None
        fallback = c["name"] if c.get("size_qualifier") is None else f"{c['name']} ({c['size_qualifier']})"
        out.append({"class_index": ci, "category_id": cid, "name": names.get(cid, fallback) if cid is not None
                    else fallback, "spawned": len(objs), "reasons": _reasons(objs)})
    return out


def scene_density(meta: Mapping[str, Any]) -> dict[str, Any]:
    """One scene's spawned / kept counted objects and distractors, drop reasons and empty classes."""
    objects = meta["objects"]
    counted = [o for o in objects if o["role"] == "counted"]
    distractors = [o for o in objects if o["role"] == "distractor"]
    return {
        "scene_id": meta["scene_id"], "seed": meta.get("seed"),
        "container": meta["spec"].get("container") is not None,
        "classes": len(meta["spec"]["classes"]),
        "counted_spawned": len(counted), "counted_kept": sum(o["status"] == KEPT for o in counted),
        "distractors_spawned": len(distractors), "distractors_kept": sum(o["status"] == KEPT for o in distractors),
        "counted_drops": _reasons(counted), "distractor_drops": _reasons(distractors),
        "classes_without_instances": classes_without_instances(meta),
    }


def _ratio(a: float, b: float) -> Optional[float]:
    return round(a / b, 4) if b else None


def _group(rows: list[Mapping[str, Any]]) -> dict[str, Any]:
    spawned = sum(r["counted_spawned"] for r in rows)
    kept = sum(r["counted_kept"] for r in rows)
    return {"scenes": len(rows), "counted_spawned": spawned, "counted_kept": kept,
            "retention": _ratio(kept, spawned), "mean_counted_kept": _ratio(kept, len(rows))}


def _add(total: "Counter[str]", d: Mapping[str, int]) -> None:
    for k, v in d.items():
        total[k] += int(v)


def summarise_density(rows: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Pool :func:`scene_density` rows: counted retention (kept / spawned) overall and in container /
    no-container scenes, means per scene, distractors, drop reasons (counts and shares of the spawned
    bodies), the share lost off the floor (below_floor + flung_out over all spawned bodies) and the
    classes that ended with no visible instance (how many, and their objects' drop reasons)."""
    rows = list(rows)
    counted_drops: Counter[str] = Counter()
    distractor_drops: Counter[str] = Counter()
    empty_reasons: Counter[str] = Counter()
    empty = 0
    for r in rows:
        _add(counted_drops, r["counted_drops"])
        _add(distractor_drops, r["distractor_drops"])
        for c in r["classes_without_instances"]:
            empty += 1
            _add(empty_reasons, c["reasons"])
    n = len(rows)
    d_spawned = sum(r["distractors_spawned"] for r in rows)
    d_kept = sum(r["distractors_kept"] for r in rows)
    bodies = sum(r["counted_spawned"] for r in rows) + d_spawned
    lost = sum(counted_drops[k] + distractor_drops[k] for k in LOST_OFF_FLOOR)
    all_drops = counted_drops + distractor_drops
    counted = _group(rows)
    return {
        "scenes": n, **{k: v for k, v in counted.items() if k != "scenes"},
        "container": _group([r for r in rows if r["container"]]),
        "no_container": _group([r for r in rows if not r["container"]]),
        "distractors_spawned": d_spawned, "distractors_kept": d_kept,
        "mean_distractors_spawned": _ratio(d_spawned, n), "mean_distractors_kept": _ratio(d_kept, n),
        "counted_drops": dict(sorted(counted_drops.items())),
        "distractor_drops": dict(sorted(distractor_drops.items())),
        "drop_shares": {k: _ratio(v, bodies) for k, v in sorted(all_drops.items())},
        "lost_off_floor": lost, "lost_off_floor_share": _ratio(lost, bodies),
        "classes": sum(r["classes"] for r in rows), "classes_without_instances": empty,
        "classes_without_instances_reasons": dict(sorted(empty_reasons.items())),
    }
