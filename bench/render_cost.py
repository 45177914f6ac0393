"""Where one canonical render's CPU goes (issue 69, item 1): the same scene rendered with pieces on and off.

Usage: .venv/bin/python bench/render_cost.py [--faces 1200000] [--texture-px 4096] [--resolution 512]
                                             [--samples 16] [--smoke]

One capture-like model (bench/big_meshes.py: a lumpy scan with a JPEG texture, in a temporary folder) is
imported once with the canonical render's own functions (``mixcount.engine.canonical_render``), then rendered
with 1 Cycles thread (as each of 2 workers on 2 cores) at: a 16 px image with 1 sample and no denoising
(scene sync, BVH and texture load: the fixed part), the full size with 1 sample, with all samples and no
denoising (the path tracing), and with OIDN at the heavy path's prefilter (FAST) and the light path's
(ACCURATE). Each figure is the CPU seconds of the render call (``time.process_time``, which counts Cycles'
thread). Prints a line per render on stderr and one JSON line on stdout:
{"bench": "render_cost", "faces": F, "cpu_s": {"import": ..., "sync_bvh_16px_1spp": ..., ...},
 "per_sample_cpu_s": ...}. ``--smoke``: 20,000 faces, 256 px texture, 64 px, 4 samples (the suite runs it).

bpy runs in this process, so this script imports nothing that loads a second Embree (pymeshlab) first.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def timed_render(scene: Any, *, resolution: int, samples: int, denoise: bool, prefilter: str = "ACCURATE") -> float:
    """CPU seconds of one Cycles render of ``scene`` at these settings (1 thread)."""
    import bpy

    from mixcount.engine import canonical_render as C

    C.configure_render(scene, resolution=resolution, samples=samples, denoise=denoise, threads=1)
    if denoise:
        scene.cycles.denoising_prefilter = prefilter
    t = time.process_time()
    bpy.ops.render.render(write_still=True)
    return round(time.process_time() - t, 2)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--faces", type=int, default=1_200_000)
    ap.add_argument("--texture-px", type=int, default=4096)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--smoke", action="store_true")
    args = ap.parse_args(argv)
    if args.smoke:
        args.faces, args.texture_px, args.resolution, args.samples = 20_000, 256, 64, 4

    from mixcount.engine.worker_main import import_bpy

    import_bpy(1)  # as a worker of 2 on 2 cores: TBB sized to its one Cycles thread (docs/blender.md)
    import big_meshes as B

    from mixcount.engine import canonical_render as C

    with tempfile.TemporaryDirectory(prefix="mixcount-render-cost-") as tmp:
        glb = Path(tmp) / "Capture" / "3d-asset.glb"
        glb.parent.mkdir()
        verts, tris, uv = B.lumpy_grid(args.faces, seed=0, radius=0.04)
        B.write_textured_glb(glb, verts, tris, uv, args.texture_px, seed=0)

        cpu: dict[str, float] = {}
        t = time.process_time()
        scene = C.reset_scene()
        objects = C.import_model(glb)
        cpu["import"] = round(time.process_time() - t, 2)
        C.orient_to_catalog(glb, "Y")
        C.use_vertex_colours(objects)
        pts = C.centre_objects(objects)
        C.add_lighting(scene, world_strength=1.0, sun_strength=3.0, azimuth_deg=30.0)
        C.add_camera(pts, elevation_deg=30.0, azimuth_deg=30.0, margin=0.1)
        scene.render.filepath = str(Path(tmp) / "out.png")
        full, n = args.resolution, args.samples
        runs = {
            "sync_bvh_16px_1spp": dict(resolution=16, samples=1, denoise=False),
            f"{full}px_1spp": dict(resolution=full, samples=1, denoise=False),
            f"{full}px_{n}spp": dict(resolution=full, samples=n, denoise=False),
            f"{full}px_{n}spp_denoise_FAST": dict(resolution=full, samples=n, denoise=True, prefilter="FAST"),
            f"{full}px_{n}spp_denoise_ACCURATE": dict(resolution=full, samples=n, denoise=True, prefilter="ACCURATE"),
        }
        for name, settings in runs.items():
            cpu[name] = timed_render(scene, **settings)  # type: ignore[arg-type]
            print(f"{name}: {cpu[name]} CPU-s", file=sys.stderr)
        faces = C.triangle_count(objects)
    per_sample = round((cpu[f"{full}px_{n}spp"] - cpu[f"{full}px_1spp"]) / max(1, n - 1), 3)
    print(json.dumps({"bench": "render_cost", "faces": faces, "texture_px": args.texture_px, "resolution": full,
                      "samples": n, "cpu_s": cpu, "per_sample_cpu_s": per_sample}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
