"""Render one finished scene with several Cycles settings (bpy; ``bench/render_quality.py`` runs it).

    python -m mixcount.engine.render_sweep JOB.json

``JOB.json``: ``{"request": <SceneRequest>, "candidates": [{"name", "samples", "denoise_prefilter", "cycles": {...},
"border": [x0, x1, y0, y1] | null}], "repeats": N, "out": DIR}``. The scene is built and settled once,
exactly as the ``scene`` operation does (:func:`mixcount.engine.scene_job.run_scene`: physics, placement,
visibility drops, passes); then, in place of its RGB render, every candidate renders cam_0 at the stage's
resolution into ``DIR/<name>.png`` (``repeats`` rounds, candidates in the same order each round, so a slow
spell of this shared machine hits them alike). ``cycles`` maps :class:`mixcount.scene.spec.CyclesSpec`
field names to values, applied over the stage's own settings; the denoiser switch stays the stage's.
``border`` renders only that normalised window of the frame (Blender's border, y from the bottom; the reference of a stage can be a window);
``once`` renders it in the first round only; ``seed`` Cycles' sampling seed (0, the worker's, when absent: a reference needs another one, or its first
samples are the candidates' own and it favours them).

Writes ``DIR/sweep.json``: per candidate the seconds of each round, what Cycles was set to (read back) and
its border. Outside a border the image holds whatever the render buffer held (docs/blender.md).
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any


def sweep(job: dict[str, Any]) -> dict[str, Any]:
    from mixcount.engine import render_passes as P
    from mixcount.engine.scene_job import run_scene
    from mixcount.worker.contract import SceneRequest

    out = Path(job["out"])
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {"candidates": {}}

    def render_all(state: Any) -> None:
        scene = state.scene
        scene.camera = state.cam_objs[0]
        base = state.spec.render
        for rnd in range(int(job.get("repeats", 1))):
            for cand in job["candidates"]:
                if rnd > 0 and cand.get("once"):  # a reference: one round is enough
                    continue
                render = dataclasses.replace(base, samples=int(cand["samples"]),
                                             denoise_prefilter=str(cand["denoise_prefilter"]),
                                             cycles=dataclasses.replace(base.cycles, **cand["cycles"]))
                applied = P.configure_rgb(scene, render)
                scene.cycles.seed = int(cand["seed"]) if "seed" in cand else 0  # the worker renders with seed 0
                applied["seed"] = int(scene.cycles.seed)
                border = cand.get("border") or None
                with P.border(scene, border):
                    t0 = time.perf_counter()
                    P.render_to(scene, out / f"{cand['name']}.png")
                    seconds = time.perf_counter() - t0
                entry = results["candidates"].setdefault(cand["name"], {"seconds": [], "applied": applied,
                                                                        "border": border})
                entry["seconds"].append(round(seconds, 3))
                print(json.dumps({"round": rnd, "candidate": cand["name"], "seconds": round(seconds, 3)}), flush=True)

    t0 = time.perf_counter()
    result = run_scene(SceneRequest.from_dict(job["request"]), render=render_all)
    results.update(status=result.status, timings=result.timings, seconds=round(time.perf_counter() - t0, 3),
                   counted_kept=sum(1 for o in result.objects if o.role == "counted" and o.status == "kept"),
                   distractors_kept=sum(1 for o in result.objects if o.role == "distractor" and o.status == "kept"))
    (out / "sweep.json").write_text(json.dumps(results, indent=1))
    return results


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    sweep(json.loads(Path(argv[0]).read_text()))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
