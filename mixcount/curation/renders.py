"""`catalog render`: canonical white-background renders of catalog objects (the external exemplars).

Each active object gets a ``canonical`` view (and ``view_<k>`` extra views when ``canonical_render.extra_views`` > 0)
rendered by bpy in worker processes (:mod:`mixcount.worker.canonical_runner`). Files live under
``catalog.renders_dir`` (``renders/<catalog>/`` beside the database: the catalog's own folder, since row ids
repeat between catalogs that share a folder) as ``obj_<id>.png`` (RGB on pure white) plus
``obj_<id>_mask.png`` (coverage); rows in table ``renders`` record path, size, a hash of the model's
content and up axis (:func:`model_key`) and a hash of the render settings. A render stored outside the
catalog's own folder (catalogs from before per-catalog folders wrote ``renders/obj_<id>.png``, a file
another catalog in the same folder may have overwritten) still resolves, but counts as stale: the next
``catalog render`` renders it again into the catalog's folder.

Resumable: an object is skipped when every view's row matches its current model key and the current
settings hash (:func:`object_settings_hash`: the heavy path's settings count only for heavy objects) and the
files exist. A failed object gets a row with ``error`` (reason) and is retried on
the next run; the batch always goes on.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.db import Catalog
from mixcount.catalog.hashing import json_hash
from mixcount.catalog.materials import object_look
from mixcount.catalog.models import STATUS_ACTIVE, STATUS_EXCLUDED, CatalogObject, Render, utcnow
from mixcount.catalog.records import ingest_appearance
from mixcount.config import CanonicalRenderConfig
from mixcount.progress import ProgressReporter, as_reporter
from mixcount.worker.canonical_contract import CANONICAL, CanonicalRequest, CanonicalSettings, canonical_views

RENDER_VERSION = "canonical-v3"  # bump when the renderer changes what a render looks like (v2: vertex colours;
# v3: palette looks for uncoloured parts, the albedo pass written beside each view)
SETTING_KEYS = ("resolution", "samples", "denoise", "elevation_deg", "azimuth_deg", "extra_views", "margin",
                "world_strength", "sun_strength")
HEAVY_VERSION = "heavy-v1"  # bump when the heavy path (engine.canonical_render.configure_heavy) changes its picture
HEAVY_SETTING_KEYS = ("heavy_denoise_prefilter",)


@dataclass
class RenderSummary:
    objects: int = 0
    rendered: int = 0
    skipped: int = 0
    failed: int = 0
    settings_hash: str = ""  # of a light object (object_settings_hash); heavy objects carry their own
    failures: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def render_settings(config: CanonicalRenderConfig) -> dict[str, Any]:
    """The ``[canonical_render]`` keys that change the picture, plus the renderer version."""
    settings = {key: getattr(config, key) for key in SETTING_KEYS}
    settings["version"] = RENDER_VERSION
    return settings


def settings_hash(settings: dict[str, Any]) -> str:
    return json_hash(settings)[:32]


def is_heavy(config: CanonicalRenderConfig, obj: CatalogObject) -> bool:
    """Whether ``obj`` takes the heavy render path: its ``face_count`` (triangles, as trimesh read the file
    at ingest) over ``heavy_faces``; an object without a face count is light. The one rule for both the
    path (sent in the request: :func:`canonical_request`) and the settings hash its rows carry
    (:func:`object_settings_hash`)."""
    return obj.face_count is not None and int(obj.face_count) > config.heavy_faces


def heavy_render_settings(config: CanonicalRenderConfig) -> dict[str, Any]:
    """A heavy object's settings: :func:`render_settings` plus the heavy path's version and keys."""
    settings = render_settings(config)
    settings.update({key: getattr(config, key) for key in HEAVY_SETTING_KEYS}, heavy=HEAVY_VERSION)
    return settings


def object_settings_hash(config: CanonicalRenderConfig, obj: CatalogObject) -> str:
    """The settings hash an object's render rows must carry to be up to date.

    A light object (face_count <= heavy_faces, or unknown) hashes :func:`render_settings` alone: exactly the
    hash every render had before the heavy path existed, so a catalog rendered then keeps its light
    renders, and neither ``heavy_faces`` nor ``heavy_denoise_prefilter`` ever re-renders a light object. A
    heavy object hashes :func:`heavy_render_settings`: its render came from the other path (one render,
    FAST prefilter), so it renders again once, and again whenever ``heavy_denoise_prefilter`` or
    :data:`HEAVY_VERSION` changes. Changing ``heavy_faces`` re-renders exactly the objects whose side of
    the threshold changed. The value of ``heavy_faces`` itself is in neither hash: it only picks the path.
    The worker renders the path :func:`is_heavy` picks (the request carries it), so the hash always names
    the path the picture came from."""
    settings = heavy_render_settings(config) if is_heavy(config, obj) else render_settings(config)
    return settings_hash(settings)


def view_names(extra_views: int) -> list[str]:
    """The views each object gets, named as the worker names them (one list: contract.canonical_views)."""
    return [name for name, _ in canonical_views(int(extra_views), 0.0)]


def canonical_request(config: CanonicalRenderConfig, obj: CatalogObject, out_dir: Path,
                      look: Optional[tuple[float, ...]] = None) -> CanonicalRequest:
    """The worker request for one object's renders, every setting from ``[canonical_render]`` (threads are the
    runner's: it shares the cores among its workers); ``look`` for its parts without a colour."""
    return CanonicalRequest(model_path=obj.model_path, out_dir=str(out_dir), stem=f"obj_{obj.id:06d}",
                            threads=config.threads, settings=CanonicalSettings.from_config(config),
                            up_axis=obj.source_up_axis or "", look=look, heavy=is_heavy(config, obj),
                            stand_in_materials=look is not None and colourless(obj))


def colourless(obj: CatalogObject) -> bool:
    """True for an OBJ in which ingest read no colour (appearance ``none``: its .mtl missing or never
    written): the material Blender's importer makes for its ``usemtl`` anyway is a stand-in. (Other formats
    get no material from their importer where they have no colour.)"""
    return str(obj.model_path or "").lower().endswith(".obj") and ingest_appearance(obj) == "none"


def render_look(palette: Any, obj: CatalogObject) -> Optional[tuple[float, ...]]:
    """The palette look an untextured object's render gives its parts without a colour (None: textured,
    or no palette)."""
    if palette is None or obj.textured:
        return None
    look = object_look(palette, name=obj.name, category=obj.category or "", metadata_json=obj.metadata_json,
                       content_hash=obj.content_hash or "")
    return None if look is None else look.as_tuple()


def model_key(obj: CatalogObject, look: Optional[tuple[float, ...]] = None) -> str:
    """What a render depends on besides the settings: the model's content, the up axis the catalog
    reads it with (a corrected up axis renders the object again) and the palette look of its parts without a
    colour. Stored as ``renders.model_hash``."""
    tail = "" if look is None else "|" + ",".join(f"{v:.4f}" for v in look) + ("|stand-ins" if colourless(obj) else "")
    return hashlib.sha256(f"{obj.content_hash}|{obj.source_up_axis or ''}{tail}".encode()).hexdigest()


def mask_path_for(render_path: Path | str) -> Path:
    """The coverage mask written next to a render (``x.png`` -> ``x_mask.png``)."""
    p = Path(render_path)
    return p.with_name(f"{p.stem}_mask.png")


def albedo_path_for(render_path: Path | str) -> Path:
    """The albedo (surface colour without shading, RGBA) written next to a render (``x.png`` ->
    ``x_albedo.png``; :func:`mixcount.engine.canonical_render.render_albedo`)."""
    p = Path(render_path)
    return p.with_name(f"{p.stem}_albedo.png")


def canonical_render_path(session: Session, object_id: int) -> Path | None:
    """Absolute path of an object's canonical render, or None when it has none (or it failed/vanished)."""
    row = session.scalar(
        select(Render).where(Render.object_id == object_id, Render.view == CANONICAL, Render.error.is_(None))
    )
    if row is None or not row.path or not Path(row.path).is_file():
        return None
    return Path(row.path)


def _up_to_date(rows: dict[str, Render], obj: CatalogObject, views: list[str], shash: str, own_dir: Path,
                look: Optional[tuple[float, ...]] = None) -> bool:
    for view in views:
        row = rows.get(view)
        if row is None or row.error or not row.path or not Path(row.path).is_file():
            return False
        if Path(row.path).parent != own_dir.resolve():
            return False  # a shared folder of an older catalog: possibly another catalog's picture
        if row.model_hash != model_key(obj, look) or row.settings_hash != shash:
            return False
    return True


def _upsert(session: Session, object_id: int, view: str) -> Render:
    row = session.scalar(select(Render).where(Render.object_id == object_id, Render.view == view))
    if row is None:
        row = Render(object_id=object_id, view=view)
        session.add(row)
    return row


def canonical_fault(result: Any) -> Optional[str]:
    """Why one of a canonical result's views is no render of its object (Blender's missing-image magenta
    over the object's mask, or black everywhere: :func:`mixcount.catalog.media_check.render_fault`), or None."""
    from mixcount.catalog.media_check import render_fault

    for v in result.views:
        if Path(v.path).is_file():
            fault = render_fault(v.path, v.mask_path)
            if fault:
                return f"{Path(v.path).name}: {fault}"
    return None


def damaged_textures(session: Session) -> dict[int, str]:
    """Object id -> the reason of its first ``damaged_texture`` flag (a texture that did not decode whole at
    ingest: :func:`mixcount.catalog.media_check.texture_warnings`). Such an object is not rendered: Blender
    would paint the image magenta or black, or decode a declared 40000 x 40000 image."""
    from mixcount.catalog.models import Flag

    out: dict[int, str] = {}
    for oid, reason in session.execute(select(Flag.object_id, Flag.reason).where(Flag.kind == "damaged_texture")
                                       .order_by(Flag.id)):
        out.setdefault(int(oid), str(reason))
    return out


def render_catalog(
    catalog: Catalog,
    config: CanonicalRenderConfig,
    *,
    object_ids: Iterable[int] | None = None,
    include_excluded: bool = False,
    force: bool = False,
    progress: ProgressReporter | bool | None = None,
    palette: Any = None,
) -> RenderSummary:
    """Render every active (and optionally excluded) object whose render is missing or stale; ``palette``
    (``[palette]``) gives untextured objects' parts without a colour their look."""
    from mixcount.worker.canonical_runner import RenderOutcome, run_jobs, run_jobs_on_ray

    settings = render_settings(config)
    shash = settings_hash(settings)
    views = view_names(config.extra_views)
    summary = RenderSummary(settings_hash=shash)
    out_dir = catalog.renders_dir
    statuses = [STATUS_ACTIVE, STATUS_EXCLUDED] if include_excluded else [STATUS_ACTIVE]
    jobs: list[tuple[str, CanonicalRequest]] = []
    refused: list[tuple[str, str]] = []  # objects whose texture did not decode at ingest: never sent to Blender
    names: dict[str, str] = {}
    hashes: dict[str, str] = {}
    shashes: dict[str, str] = {}  # object key -> its settings hash (object_settings_hash)
    with catalog.session() as session:
        damaged = damaged_textures(session)
        query = select(CatalogObject).where(CatalogObject.status.in_(statuses)).order_by(CatalogObject.id)
        if object_ids is not None:
            query = query.where(CatalogObject.id.in_(list(object_ids)))
        for obj in session.scalars(query):
            summary.objects += 1
            rows = {r.view: r for r in session.scalars(select(Render).where(Render.object_id == obj.id))}
            look = render_look(palette, obj)
            ohash = object_settings_hash(config, obj)
            if not force and _up_to_date(rows, obj, views, ohash, out_dir, look):
                summary.skipped += 1
                continue
            key = str(obj.id)
            names[key], hashes[key], shashes[key] = obj.name, model_key(obj, look), ohash
            if obj.id in damaged:
                refused.append((key, f"not rendered: {damaged[obj.id]} (flag damaged_texture: replace the file)"))
                continue
            jobs.append((key, canonical_request(config, obj, out_dir, look)))
    if not jobs and not refused:
        return summary

    bar = as_reporter(progress)
    bar.start("render", len(jobs) + len(refused))

    def on_result(outcome: RenderOutcome) -> None:
        key = outcome.key
        oid = int(key)
        fault = canonical_fault(outcome.result) if outcome.result is not None else None
        if fault:  # a magenta or black render of a textured object: failed, not recorded as its look
            outcome = RenderOutcome(key, None, fault)
        with catalog.session() as session:
            if outcome.result is not None:
                for v in outcome.result.views:
                    row = _upsert(session, oid, v.view)
                    row.path = str(Path(v.path).resolve())
                    row.width, row.height = v.width, v.height
                    row.model_hash, row.settings_hash, row.error = hashes[key], shashes[key], None
                    row.created_at = utcnow()
                summary.rendered += 1
            else:
                row = _upsert(session, oid, CANONICAL)
                row.path, row.width, row.height = None, None, None
                row.model_hash, row.settings_hash = hashes[key], shashes[key]
                row.error = str(outcome.error or "unknown render failure")
                row.created_at = utcnow()
                summary.failed += 1
                summary.failures.append({"id": oid, "name": names[key], "error": row.error})
            session.commit()
        bar.advance()

    for key, reason in refused:
        on_result(RenderOutcome(key, None, reason))
    from mixcount.catalog.step_executor import ray_tasks

    cluster = ray_tasks()  # --executor ray: the renders run as Ray tasks, the rows are written here
    try:
        if cluster is not None:
            run_jobs_on_ray(cluster, jobs, on_result=on_result, timeout_s=config.timeout_s,
                            threads_per_worker=config.threads)
        else:
            run_jobs(jobs, on_result=on_result, workers=config.workers, timeout_s=config.timeout_s,
                     threads_per_worker=config.threads)
    finally:
        bar.stop()
    return summary
