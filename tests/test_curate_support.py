"""Helpers shared by the curation tests (no tests here): small libraries of real GLB files written with
trimesh, ingested into a real SQLite catalog, and canonical renders drawn with PIL where a test needs
render pixels but not bpy."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw
from sqlalchemy import select

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.models import CaptionSet, CatalogObject, Render
from mixcount.config import load_config


def quick_config(*overrides: str):
    return load_config(["configs/quick.toml"], list(overrides))


def vertex_coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def textured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    uv = np.c_[mesh.vertices[:, 0] > 0, mesh.vertices[:, 1] > 0].astype(float)
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (8, 8), rgb))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return mesh


def drawing(shape: str, colour: tuple[int, int, int], stripe: tuple[int, int, int], size: int = 64) -> Image.Image:
    """A fake canonical render: a white square with one shape and a stripe across it."""
    img = Image.new("RGB", (size, size), (255, 255, 255))
    d = ImageDraw.Draw(img)
    box = (8, 8, size - 9, size - 9)
    if shape == "circle":
        d.ellipse(box, fill=colour)
    elif shape == "tall":
        d.rectangle((22, 4, size - 23, size - 5), fill=colour)
    else:
        d.rectangle(box, fill=colour)
    d.rectangle((8, size // 2 - 4, size - 9, size // 2 + 3), fill=stripe)
    return img


def put_render(catalog, object_id: int, img: Image.Image) -> Path:
    """Store ``img`` (on white) as the object's canonical render with a mask of its non-white pixels."""
    catalog.renders_dir.mkdir(parents=True, exist_ok=True)
    path = catalog.renders_dir / f"obj_{object_id:06d}.png"
    img.save(path)
    arr = np.asarray(img.convert("RGB"))
    Image.fromarray(np.where((arr < 250).any(axis=2), 255, 0).astype(np.uint8), "L").save(
        path.with_name(f"{path.stem}_mask.png"))
    with catalog.session() as s:
        obj = s.get(CatalogObject, object_id)
        row = s.scalar(select(Render).where(Render.object_id == object_id, Render.view == "canonical"))
        if row is None:
            row = Render(object_id=object_id, view="canonical")
            s.add(row)
        row.path, row.width, row.height = str(path.resolve()), img.width, img.height
        row.model_hash, row.settings_hash, row.error = obj.content_hash, "test", None
        s.commit()
    return path


def ingest(catalog, root: Path) -> dict[str, CatalogObject]:
    ingest_paths(catalog, [root], config=quick_config())
    with catalog.session() as s:
        return {Path(o.model_path).stem: o for o in s.scalars(select(CatalogObject))}


def build_library(root: Path) -> Path:
    """Eleven objects: three planted duplicate pairs, four distinct ones, a degenerate and a giant."""
    root.mkdir(parents=True)
    vertex_coloured(trimesh.creation.box(extents=(0.05, 0.03, 0.02)), (220, 30, 30)).export(root / "box.glb")
    shutil.copy(root / "box.glb", root / "box_copy.glb")
    vertex_coloured(trimesh.creation.cylinder(radius=0.02, height=0.09, sections=32), (30, 160, 60)).export(root / "cyl.glb")
    textured(trimesh.creation.cylinder(radius=0.02, height=0.09, sections=32), (160, 40, 160)).export(root / "cyl_recolour.glb")
    vertex_coloured(trimesh.creation.icosphere(subdivisions=3, radius=0.03), (30, 60, 220)).export(root / "ball.glb")
    vertex_coloured(trimesh.creation.icosphere(subdivisions=3, radius=0.05), (30, 60, 220)).export(root / "ball_big.glb")
    vertex_coloured(trimesh.creation.cone(radius=0.03, height=0.05, sections=32), (240, 200, 30)).export(root / "cone.glb")
    vertex_coloured(trimesh.creation.capsule(height=0.06, radius=0.015), (120, 70, 30)).export(root / "capsule.glb")
    vertex_coloured(trimesh.creation.annulus(r_min=0.02, r_max=0.04, height=0.01), (90, 90, 90)).export(root / "ring.glb")
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [0.05, 0, 0], [0.05, 0.05, 0], [0, 0.05, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    vertex_coloured(flat, (200, 200, 200)).export(root / "flat.glb")
    vertex_coloured(trimesh.creation.box(extents=(3.0, 2.0, 1.0)), (150, 150, 150)).export(root / "giant.glb")
    return root


RENDERS = {
    "box": ("square", (220, 30, 30), (250, 230, 60)),
    "box_copy": ("square", (220, 30, 30), (250, 230, 60)),
    "cyl": ("tall", (30, 160, 60), (20, 20, 20)),
    "cyl_recolour": ("tall", (160, 40, 160), (20, 20, 20)),
    "ball": ("circle", (30, 60, 220), (240, 240, 240)),
    "ball_big": ("circle", (30, 60, 220), (240, 240, 240)),
    "cone": ("circle", (240, 200, 30), (200, 60, 20)),
    "capsule": ("tall", (120, 70, 30), (240, 240, 240)),
    "ring": ("circle", (90, 90, 90), (255, 255, 255)),
    "giant": ("square", (150, 150, 150), (60, 60, 60)),
}


def library_catalog(catalog, tmp_path: Path) -> dict[str, CatalogObject]:
    objs = ingest(catalog, build_library(tmp_path / "lib"))
    for stem, (shape, colour, stripe) in RENDERS.items():
        put_render(catalog, objs[stem].id, drawing(shape, colour, stripe))
    put_render(catalog, objs["flat"].id, Image.new("RGB", (64, 64), (255, 255, 255)))  # blank render
    return objs


def add_captions(catalog, object_id: int, short: str) -> None:
    with catalog.session() as s:
        s.add(CaptionSet(object_id=object_id, captioner="stub", provider="stub", model="stub", prompt_version="t",
                         short=short, concise=f"concise {short}", detailed=f"detailed {short}", response_hash="0",
                         active=True))
        s.commit()
