"""Sampler pools straight from a generated demo library, without a catalog database.

Tests and the benchmarks need realistic scenes (textured GLBs, a container) but not the whole
ingest / caption / split chain: :func:`pool_from_demo_library` reads the library's
``ground_truth.json`` (true Z-up dimensions) and returns :class:`~mixcount.scene.object_records.ObjectRecord`
s, every working object in one split, ids in folder order. With ``proxy_dir`` every object also gets
its convex collision proxy (:mod:`mixcount.catalog.proxies`), as ingest would build it.

:func:`heavy_demo_library` turns the light demo library into a capture-like one: every model is
subdivided (midpoint, 1 -> 4 triangles, UVs and vertex colours interpolated, textures and materials
kept) until it has at least ``min_faces`` faces, the size of a real photogrammetry capture.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any, Optional

import numpy as np

from mixcount.scene.object_records import ObjectRecord, fallback_captions


def _frame(model: Path, digest: str, units: Optional[str], up_axis: Optional[str]) -> tuple[str, dict[str, str]]:
    """The key of a model's proxy / collision file and the frame to read the model in (units, up axis as
    :func:`mixcount.frame.source_frame` resolves them, the converter's rule). An OBJ in centimetres read
    as metres gives a proxy 100x the object (it flung whole scenes apart), so the frame is part of the
    key: a file built in another frame is never reused."""
    from mixcount.frame import source_frame

    _scale, name, up = source_frame(model, units, up_axis)
    return hashlib.sha256(f"{digest}|{name}|{up}".encode()).hexdigest(), {"units": name, "up_axis": up}


def _proxy_for(model: Path, digest: str, proxy_dir: Path, max_vertices: int, units: Optional[str],
               up_axis: Optional[str]) -> str:
    from mixcount.catalog.mesh import load_normalised
    from mixcount.catalog.proxies import build_proxy, proxy_name

    key, frame = _frame(model, digest, units, up_axis)
    out = proxy_dir / proxy_name(key, max_vertices)
    if not out.is_file():
        build_proxy(np.asarray(load_normalised(model, **frame).mesh.vertices), out, max_vertices)
    return str(out.resolve())


def _collision_for(model: Path, digest: str, out_dir: Path, face_budget: int, units: Optional[str],
                   up_axis: Optional[str]) -> str:
    from mixcount.catalog.mesh import build_collision_mesh, load_normalised

    key, frame = _frame(model, digest, units, up_axis)
    out = out_dir / f"{key[:32]}_{face_budget}.ply"
    build_collision_mesh(load_normalised(model, **frame).mesh, out, face_budget)
    return str(out.resolve())


def pool_from_demo_library(root: Path, *, split: str = "train", proxy_dir: Optional[Path] = None,
                           proxy_max_vertices: Optional[int] = None) -> list[ObjectRecord]:
    """ObjectRecords for every non-broken object of the demo library at ``root``. With ``proxy_dir``,
    as ingest would store them: collision proxies of at most ``proxy_max_vertices``
    (``ingest.proxy_max_vertices`` of configs/default.toml when None), and for containers the decimated
    collision mesh (``ingest.collision_face_budget``) they collide through. Without one a container
    collides through its render mesh, which on a capture-sized mesh makes Bullet crawl (a 300k-triangle
    tray held one 31-object scene in physics for over 10 minutes)."""
    from mixcount.config import load_config

    ingest = load_config().ingest
    if proxy_max_vertices is None:
        proxy_max_vertices = ingest.proxy_max_vertices
    root = Path(root)
    truth = json.loads((root / "ground_truth.json").read_text())
    broken = {b["folder"] for b in truth.get("broken", [])}
    pool = []
    for k, rec in enumerate(sorted(truth["objects"], key=lambda r: r["folder"]), start=1):
        folder = rec["folder"]
        if folder in broken:
            continue
        model = root / rec["model"]
        digest = hashlib.sha256(model.read_bytes()).hexdigest()
        name = folder.split("_")[-1].lower()
        caps = fallback_captions(f"{name} {rec['category']}", rec["category"])
        units, up_axis = rec.get("units"), rec.get("up_axis")
        proxy = (_proxy_for(model, digest, Path(proxy_dir), proxy_max_vertices, units, up_axis)
                 if proxy_dir is not None else None)
        collision = (_collision_for(model, digest, Path(proxy_dir), ingest.collision_face_budget, units, up_axis)
                     if proxy_dir is not None and rec["container"] else None)
        pool.append(ObjectRecord(
            object_id=k, name=folder, category=rec["category"], dims=tuple(float(v) for v in rec["dims_m"]),
            captions=caps, split=split, model_path=str(model.resolve()), content_hash=digest, proxy_path=proxy,
            collision_path=collision,
            container=bool(rec["container"]), source_units=units, source_up_axis=up_axis,
        ))
    return pool


def ensure_demo_pool(root: Path, *, seed: int = 0, split: str = "train", proxy_dir: Optional[Path] = None,
                     proxy_max_vertices: Optional[int] = None) -> list[ObjectRecord]:
    """Generate the demo library at ``root`` unless it is already there, then return its pool.

    The benchmarks reuse a library across runs with ``--work DIR``; generating it is deterministic.
    """
    from mixcount.demo.library import generate_demo_library

    root = Path(root)
    if not (root / "ground_truth.json").exists():
        generate_demo_library(root, seed=seed)
    return pool_from_demo_library(root, split=split, proxy_dir=proxy_dir, proxy_max_vertices=proxy_max_vertices)


def _subdivided(geom: Any, min_faces: int) -> Any:
    """One trimesh geometry midpoint-subdivided until it has >= ``min_faces`` faces, visuals kept."""
    import trimesh
    from trimesh.remesh import subdivide

    visual = geom.visual
    uv = getattr(visual, "uv", None)
    uv = np.asarray(uv, dtype=np.float64) if uv is not None and len(uv) == len(geom.vertices) else None
    colours = None
    if visual.kind == "vertex":
        colours = np.asarray(visual.vertex_colors, dtype=np.float64)
    elif getattr(visual, "vertex_attributes", None) is not None and "color" in visual.vertex_attributes:
        colours = np.asarray(visual.vertex_attributes["color"], dtype=np.float64)
    attrs = [np.asarray(geom.vertices, dtype=np.float64)] + [a for a in (uv, colours) if a is not None]
    stacked, faces = np.hstack(attrs), np.asarray(geom.faces)
    while len(faces) < min_faces:
        stacked, faces = subdivide(stacked, faces)
    verts = stacked[:, :3]
    col = 3
    if uv is not None:
        uv, col = stacked[:, col:col + 2], col + 2
    if colours is not None:
        colours = np.clip(np.round(stacked[:, col:col + colours.shape[1]]), 0, 255).astype(np.uint8)
    if uv is not None:
        new_visual: Any = trimesh.visual.TextureVisuals(uv=uv, material=visual.material)
        if colours is not None:
            new_visual.vertex_attributes["color"] = colours
    elif colours is not None:
        new_visual = trimesh.visual.ColorVisuals(vertex_colors=colours)
    else:
        new_visual = visual.copy() if visual.kind == "texture" else None
    return trimesh.Trimesh(vertices=verts, faces=faces, visual=new_visual, process=False)


def heavy_demo_library(light_root: Path, heavy_root: Path, *, min_faces: int = 200_000) -> Path:
    """Copy the demo library at ``light_root`` to ``heavy_root`` with every model subdivided to at least
    ``min_faces`` faces (kept if already there); broken traps are copied as they are. Returns heavy_root."""
    import trimesh

    light_root, heavy_root = Path(light_root), Path(heavy_root)
    if (heavy_root / "ground_truth.json").exists():
        return heavy_root
    truth = json.loads((light_root / "ground_truth.json").read_text())
    broken = {b["folder"] for b in truth.get("broken", [])}
    heavy_root.mkdir(parents=True, exist_ok=True)
    for folder in sorted(d.name for d in light_root.iterdir() if d.is_dir()):
        src, dst = light_root / folder, heavy_root / folder
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(src, dst)
        if folder in broken or not (src / "3d-asset.glb").is_file():
            continue
        scene = trimesh.load(str(src / "3d-asset.glb"), force="scene", process=False)
        total = sum(len(g.faces) for g in scene.geometry.values()) or 1
        for name, geom in list(scene.geometry.items()):
            share = max(1, int(np.ceil(min_faces * len(geom.faces) / total)))
            scene.geometry[name] = _subdivided(geom, share)
        (dst / "3d-asset.glb").write_bytes(scene.export(file_type="glb"))
    shutil.copy2(light_root / "ground_truth.json", heavy_root / "ground_truth.json")
    return heavy_root


def ensure_heavy_demo_pool(work: Path, *, split: str = "train", min_faces: int = 200_000,
                           proxy_dir: Optional[Path] = None, proxy_max_vertices: Optional[int] = None) -> list[ObjectRecord]:
    """The capture-like pool under ``work/heavy`` (built from ``work/demo`` once), for the benchmarks."""
    from mixcount.demo.library import generate_demo_library

    light = Path(work) / "demo"
    if not (light / "ground_truth.json").exists():
        generate_demo_library(light, seed=0)
    heavy = heavy_demo_library(light, Path(work) / f"heavy{min_faces // 1000}k", min_faces=min_faces)
    return pool_from_demo_library(heavy, split=split, proxy_dir=proxy_dir, proxy_max_vertices=proxy_max_vertices)
