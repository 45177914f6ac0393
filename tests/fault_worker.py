"""A bpy worker entry for tests only: ``python -m tests.fault_worker`` serves the production handlers of
:mod:`mixcount.blender.worker_main` plus faults the tests of timeouts and crashes need:

* ``{"op": "sleep", "seconds": s}`` - a hung request;
* a ``canonical`` job with ``"_test_hang_s": s`` hangs, one with ``"_test_crash": code`` kills the
  process mid-job (``os._exit``); any other job renders normally;
* ``{"op": "border_check", "stage": path, "out_dir": path, "drop": k}`` - the visibility loop's border
  re-render against a full one: a settled scene, its id pass, the ``k`` most visible objects removed, the
  changed region re-rendered and pasted, then a full render; answers which passes are identical.

Tests select it with ``monkeypatch.setattr("mixcount.blender.worker.WORKER_MODULE", "tests.fault_worker")``.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from mixcount.blender import worker_main


def sleep(req: dict[str, Any]) -> dict[str, Any]:
    time.sleep(float(req["seconds"]))
    return {"ok": True}


def canonical(req: dict[str, Any]) -> dict[str, Any]:
    job = req["job"]
    if job.get("_test_hang_s"):
        time.sleep(float(job["_test_hang_s"]))
    if job.get("_test_crash"):
        os._exit(int(job["_test_crash"]))
    return worker_main.handle_canonical(req)


def border_check(req: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    from mixcount.blender import decisions as D
    from mixcount.blender import passes as P
    from mixcount.blender import scene_job as J
    from mixcount.blender.contract import SceneRequest
    from mixcount.blender.visibility import camera_model

    state = J.load_scene(SceneRequest(stage=req["stage"], out_dir=req["out_dir"], threads=2, oracle=False))
    J.check_settled(state, J.settle(state))
    J.check_frame(state, camera_model(state.scene, state.cam_obj))
    exr = state.out_dir / "_border.exr"
    before = P.render_id_passes(state.scene, exr)
    kept = state.kept()
    seen = {state.objects[i].instance_id: int((before["index"] == state.objects[i].instance_id).sum()) for i in kept}
    drop = sorted(seen, key=lambda k: -seen[k])[: int(req["drop"])]
    region = D.changed_region(before["index"], drop)
    for i in kept:
        if state.objects[i].instance_id in drop:
            state.drop(i, D.OCCLUDED, "test")
    assert region is not None
    pasted = D.paste_region(before, P.render_id_passes(state.scene, exr, region), region)
    full = P.render_id_passes(state.scene, exr)
    return {"ok": True, "region": list(region), "dropped_px": sum(seen[k] for k in drop),
            "changed_px": int((full["index"] != before["index"]).sum()),
            "equal": {k: bool(np.array_equal(pasted[k], full[k])) for k in ("index", "depth", "normal")},
            "dropped_still_seen": int(np.isin(pasted["index"], drop).sum())}


if __name__ == "__main__":
    sys.exit(worker_main.main({**worker_main.HANDLERS, "sleep": sleep, "canonical": canonical,
                                      "border_check": border_check}))
