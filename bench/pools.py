"""Benchmark pools: the light demo library and its capture-like heavy copy, with collision proxies.

``light``: the generated demo library (a few thousand faces per object). ``heavy``: the same objects
midpoint-subdivided to >= 200k faces each, textures kept (:func:`mixcount.demo.demo_pools.heavy_demo_library`),
the size of a real photogrammetry capture. Proxies (``ingest.proxy_max_vertices``) are built only for the
assets a scene uses, as ingest would have stored them; ``proxies=False`` leaves them out (the hull of the
full render mesh, as before proxies existed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Optional

POOLS = ("light", "heavy")


def load_pool(name: str, work: Path, *, min_faces: int = 200_000) -> list[Any]:
    from mixcount.demo.demo_pools import ensure_demo_pool, ensure_heavy_demo_pool

    if name == "light":
        return ensure_demo_pool(work / "demo")
    if name == "heavy":
        return ensure_heavy_demo_pool(work, min_faces=min_faces)
    raise SystemExit(f"unknown pool {name!r}: choose from {', '.join(POOLS)}")


def with_ingest_meshes(rec: Any, container: bool, proxy_dir: Path, max_vertices: int,
                       face_budget: Optional[int] = None) -> Any:
    """``rec`` (an ObjectRecord or a spec's AssetRef) with its collision proxy and, for a container,
    its decimated collision mesh of ``face_budget`` faces (``ingest.collision_face_budget`` when None),
    as ingest stores them (each built once per model into ``proxy_dir``)."""
    from mixcount.config import load_config
    from mixcount.demo.demo_pools import _collision_for, _proxy_for

    model = Path(rec.model_path)
    budget = face_budget if face_budget is not None else load_config().ingest.collision_face_budget
    frame = (rec.source_units, rec.source_up_axis)  # a scan's OBJ in centimetres, Y-up: read as ingest reads it
    collision = (_collision_for(model, rec.content_hash, proxy_dir, budget, *frame) if container
                 else rec.collision_path)
    return dataclasses.replace(rec, proxy_path=_proxy_for(model, rec.content_hash, proxy_dir, max_vertices, *frame),
                               collision_path=collision)


def with_proxies(spec: Any, proxy_dir: Path, max_vertices: int) -> Any:
    """``spec`` with every asset's ingest meshes (:func:`with_ingest_meshes`)."""
    container = spec.container.object_id if spec.container is not None else None
    assets = tuple(with_ingest_meshes(a, a.object_id == container, proxy_dir, max_vertices) for a in spec.assets)
    return dataclasses.replace(spec, assets=assets)


def warm_mesh_cache(worker: Any, converted: dict[int, Any], mode: str) -> dict[str, str]:
    """Make the worker's .blend mesh cache of the scene's converted assets before the clock starts (a
    one-off per asset in a real run, like the conversion itself); returns asset name -> cache event."""
    if mode == "off":
        return {}
    from mixcount.worker.contract import MeshCacheRequest

    req = MeshCacheRequest(assets=tuple(str(a.visual) for a in converted.values()), mode=mode)
    return dict(worker.cache_meshes(req, timeout=1800).assets)


def run_fresh_scene(worker: Any, spec: Any, out: Path, assets: Path, *, timeout_s: float, threads: int,
                    mesh_cache: str, oracle: bool = False) -> tuple[Any, Any, dict[str, float]]:
    """One scene into an emptied ``out`` (a finished scene would be skipped, not measured): the task's
    outcome, its metadata.json (None when not written) and the worker's stage seconds."""
    import json
    import shutil

    from mixcount.config import load_config
    from mixcount.run.scene_task import WRITTEN, SceneTask, run_scene_task
    from mixcount.worker.contract import SceneOutputs

    shutil.rmtree(out, ignore_errors=True)
    outcome = run_scene_task(SceneTask(spec=spec, out_dir=str(out), assets_dir=str(assets), timeout_s=timeout_s,
                                       threads=threads, oracle=oracle,
                                       outputs=dataclasses.replace(SceneOutputs.from_config(load_config().compose),
                                                       mesh_cache=mesh_cache)), worker)
    if outcome.status != WRITTEN:
        return outcome, None, {}
    meta = json.loads((Path(outcome.path) / "metadata.json").read_text())
    return outcome, meta, worker_stages(meta)


def worker_stages(meta: dict) -> dict[str, float]:
    """A finished scene's worker stage seconds (metadata.json ``timings["worker.<stage>"]``) by stage."""
    return {k.split(".", 1)[1]: v for k, v in meta["timings"].items() if k.startswith("worker.")}


def scene_bytes(scene_dir: Path) -> dict[str, int]:
    """Bytes per file of a finished scene folder (exemplar crops summed), and the total."""
    sizes: dict[str, int] = {}
    for p in sorted(Path(scene_dir).rglob("*")):
        if p.is_file():
            key = "exemplars/" if p.parent.name == "exemplars" else p.name
            sizes[key] = sizes.get(key, 0) + p.stat().st_size
    sizes["total"] = sum(sizes.values())
    return sizes
