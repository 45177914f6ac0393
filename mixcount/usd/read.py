"""Reading mixcount facts back from a scene stage (for the Blender worker, tests and tools).

All mixcount customData is nested under one ``mixcount`` dictionary, so USD's key-path API reads it:
``prim.GetCustomDataByKey("mixcount:role")`` and
``stage.GetMetadataByDictKey("customLayerData", "mixcount:seed")``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional


@dataclass(frozen=True)
class PrimIds:
    path: str
    role: str
    object_id: int
    class_index: int
    instance_id: int


def prim_ids(prim: Any) -> Optional[PrimIds]:
    """The mixcount ids of ``prim`` or None when it carries none."""
    role = prim.GetCustomDataByKey("mixcount:role")
    if role is None:
        return None
    return PrimIds(str(prim.GetPath()), str(role), int(prim.GetCustomDataByKey("mixcount:object_id")),
                   int(prim.GetCustomDataByKey("mixcount:class_index")),
                   int(prim.GetCustomDataByKey("mixcount:instance_id")))


def stage_metadata(stage: Any) -> dict[str, Any]:
    """scene_id, seed, config_hash, split and spec (JSON string) from the stage's customLayerData."""
    data = stage.GetRootLayer().customLayerData.get("mixcount", {})
    return dict(data)


def labelled_prims(stage: Any) -> list[PrimIds]:
    """Every prim with mixcount ids, in stage order (floor, container, counted, distractors)."""
    out = []
    for prim in stage.Traverse():
        ids = prim_ids(prim)
        if ids is not None:
            out.append(ids)
    return out
