"""`catalog ingest`: discover objects, hash them, analyse changed ones in parallel, commit one by one.

Flow (see docs/ingest.md):

1. **Discover** every object under the given paths in the library layouts of
   :mod:`mixcount.catalog.layouts` (Digital Twin Catalog, Google Scanned Objects, Objaverse/ABO with side
   metadata, OmniObject3D, plain folders), auto-detected per folder or forced with ``layout``. Problems
   found here (unreadable folder, odd name, an object folder without a model) become broken objects.
   Objects whose files a loader cannot find side by side (GSO textures) are staged: linked together
   under ``data_dir/staged``.
2. **Pre-check and hash** in this process, before any mesh work: file size limit, GLB header, missing
   textures/buffers, then ``content_hash`` (model + resources) and ``ingest_hash`` (+ sidecars, the
   identity read from metadata and the settings that change facts). An object whose stored ``ingest_hash`` matches is *unchanged* and costs no
   database write; one whose content hash matches but sidecars changed gets a metadata-only update.
3. **Analyse** the rest in a process pool (:mod:`mixcount.catalog.analysis_pool`,
   :func:`mixcount.catalog.mesh.analyse_model`).
4. **Commit each object on its own**, keyed by the unique (source, source_id): a killed run leaves whole
   objects, and a rerun skips them by hash, so it finishes the job with no duplicates. An existing row is
   updated in place, which keeps its id, flags, captions, split and review history.

:func:`ingest_paths` reads as these steps: ``_discover`` (1), ``_start_run`` (the IngestRun row),
``_triage`` (2), ``_analyse_all`` (3 and 4), ``_turn_containers`` (containers whose opening faces another
axis are turned and analysed again) and ``_finish_run``.
"""

from __future__ import annotations

import json
import os
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from mixcount.catalog import hashing, layouts
from mixcount.catalog.analysis_pool import analyse_all, analysis_kwargs
from mixcount.catalog.containers import opening_warnings, refresh_containers
from mixcount.catalog.derived import derive
from mixcount.catalog.ingest_runs import close_interrupted_runs, done_running, note_running, run_failure
from mixcount.catalog.layouts import SOURCE_DTC, SOURCE_FOLDER, SOURCE_OMNI, Candidate, discover  # noqa: F401
from mixcount.catalog.layouts.parts import check_parts
from mixcount.catalog.media_check import DecodedFiles, texture_warnings
from mixcount.catalog.mesh import model_resources
from mixcount.catalog.models import (
    STATUS_ACTIVE,
    STATUS_BROKEN,
    STATUS_EXCLUDED,
    CatalogObject,
    IngestRun,
    utcnow,
)
from mixcount.catalog.naming import DTC_NAME, safe_text, singular  # noqa: F401  (re-exported)
from mixcount.catalog.orientation import (  # noqa: F401  (check_up_axis re-exported)
    check_up_axis,
    kept_evidence,
    orient,
    turn_by_openings,
)
from mixcount.catalog.proxies import refresh_proxy
from mixcount.catalog.stale import Before, StoreContext, invalidate
from mixcount.catalog.tolerated import INGEST_FLAG_KINDS, write_warning_flags  # noqa: F401  (re-exported)
from mixcount.catalog.typical_sizes import apply_size_of
from mixcount.catalog.units import check_units, decide_frame, note_units, units_summary
from mixcount.config import Config, IngestConfig
from mixcount.errors import IngestError
from mixcount.frame import GLTF_EXTENSIONS, quiet_native_output
from mixcount.library_root import bounded
from mixcount.progress import ProgressReporter, as_reporter

# the texture files the catalog decoded whole (media_check.DecodedFiles), in its data folder
DECODED_FILES = "decoded_textures.json"

# Fact columns copied from the analysis dict onto the row.
FACT_FIELDS = (
    "source_units", "source_up_axis", "dim_x", "dim_y", "dim_z", "vertex_count", "face_count",
    "watertight", "volume", "area", "textured", "geometry_hash", "collision_path", "collision_face_count",
    "proxy_path", "proxy_vertex_count", "size_source",
)


@dataclass
class IngestSummary:
    """Counts of one ingest run. Every object lands in exactly one of new/unchanged/updated/broken."""

    run_id: int | None = None
    new: int = 0
    unchanged: int = 0
    updated: int = 0
    broken: int = 0
    broken_objects: list[tuple[str, str]] = field(default_factory=list)  # (name, reason)
    layouts: dict[str, int] = field(default_factory=dict)  # objects found per layout
    containers: int = 0  # objects of the catalog that are containers after this run
    container_warnings: list[str] = field(default_factory=list)  # containers whose opening does not face up
    warnings: list[tuple[str, str]] = field(default_factory=list)  # (name, what was tolerated: a missing .mtl)
    reoriented: list[tuple[str, str, str, str]] = field(default_factory=list)  # (name, old up, new up, reason)
    invalidated: list[tuple[str, list[str]]] = field(default_factory=list)  # (name, changed columns)
    rescaled: list[tuple[str, str, str]] = field(default_factory=list)  # (name, unit, reason)
    implausible: list[tuple[str, str]] = field(default_factory=list)  # (name, unit reason): a size said, not re-read
    # links and files outside the library, not followed / not read: (path, why), once each
    refused: list[tuple[str, str]] = field(default_factory=list)
    # metadata entries of another meaning, ignored: (entry, what it must be) -> how many objects carried it
    ignored: dict[tuple[str, str], int] = field(default_factory=dict)
    # objects this run failed on (a worker crash, an internal error), not their input: (name, reason)
    failed: list[tuple[str, str]] = field(default_factory=list)
    interrupted_runs: list[int] = field(default_factory=list)  # earlier runs closed as interrupted

    @property
    def total(self) -> int:
        return self.new + self.unchanged + self.updated + self.broken

    def as_dict(self) -> dict[str, Any]:
        return {
            "run_id": self.run_id, "total": self.total, "new": self.new, "unchanged": self.unchanged,
            "updated": self.updated, "broken": self.broken, "layouts": dict(sorted(self.layouts.items())),
            "containers": self.containers, "container_warnings": list(self.container_warnings),
            "broken_objects": [{"name": n, "reason": r} for n, r in self.broken_objects],
            "warnings": [{"name": n, "warning": w} for n, w in self.warnings],
            "reoriented": [{"name": n, "old_up_axis": a, "new_up_axis": b, "reason": r}
                           for n, a, b, r in self.reoriented],
            "invalidated": [{"name": n, "changed": c} for n, c in self.invalidated],
            **units_summary(self.rescaled, self.implausible),
            "refused": [{"path": p, "reason": r} for p, r in self.refused],
            "ignored_metadata": [{"entry": e, "expected": w, "objects": n}
                                 for (e, w), n in sorted(self.ignored.items())],
            "failed": [{"name": n, "reason": r} for n, r in self.failed],
            "interrupted_runs": list(self.interrupted_runs),
        }

    def note_units(self, name: str, unit: str | None, reason: str | None) -> None:
        note_units(self.rescaled, self.implausible, name, unit, reason)


# --------------------------------------------------------------------------- hashing


@dataclass
class Prepared:
    """A candidate after pre-checks and hashing."""

    cand: Candidate
    content_hash: str | None = None
    ingest_hash: str | None = None
    settings_hash: str | None = None  # settings + assumed units/up axis: facts depend on these
    error: str | None = None


def settings_of(config: IngestConfig) -> dict[str, Any]:
    return {
        "collision_face_budget": config.collision_face_budget,
        "assume_units": config.assume_units,
        "assume_up_axis": config.assume_up_axis,
        "facts_face_budget": config.facts_face_budget,  # a big model's hash and collision mesh depend on it
        "analysis_version": 3,  # bump when mesh.py measures differently (2: units decided, issue 56; 3: sizes, 70)
    }


def proxy_budget(config: IngestConfig) -> int:
    """Vertex budget of collision proxies. Not part of the ingest hash: a changed budget only rebuilds
    proxies from the stored collision meshes (:func:`refresh_proxy`), never re-analyses a model."""
    return config.proxy_max_vertices


def prepare(cand: Candidate, *, settings: dict[str, Any], max_bytes: float, max_pixels: int,
            decoded: DecodedFiles | None = None) -> Prepared:
    """Size limit, header checks and hashes: everything that happens before mesh work. Every texture file is
    decoded whole (``max_pixels``: ``[ingest] max_image_pixels``); one that does not flags the object.
    ``decoded``: the files the catalog already decoded whole, not decoded again (a re-ingest)."""
    prep = Prepared(cand)
    if cand.error:
        prep.error = cand.error
        return prep
    assert cand.model_path is not None
    try:
        size = cand.model_path.stat().st_size
        if size > max_bytes:
            prep.error = (f"file too large: {size / 2**20:.1f} MB is over the limit of "
                          f"{max_bytes / 2**20:.1f} MB (ingest.max_file_mb)")
            return prep
        if size == 0:
            prep.error = "empty file (0 bytes)"
            return prep
        tolerated: list[str] = []
        roots = cand.roots
        if roots is not None and not roots.contains(cand.model_path):  # a staged or derived copy: its folder too
            roots = roots.widened(cand.model_path.parent)
        resources = model_resources(cand.model_path, tolerated, roots)
        tolerated.extend(texture_warnings(resources, max_pixels, decoded))  # decode before use (issue 68)
        cand.warnings.extend(w for w in tolerated if w not in cand.warnings)
        files = {"model" + cand.model_path.suffix.lower(): cand.model_path}
        files.update({f"res:{k}": v for k, v in resources.items()})
        files.update({f"companion:{k}": v for k, v in cand.companions.items()})
        prep.content_hash = hashing.files_hash(files)
        sidecar_hash = hashing.files_hash({f"side:{k}": v for k, v in cand.sidecars.items()})
        identity_hash = hashing.json_hash([cand.layout, cand.name, cand.category, cand.license, cand.metadata])
        frame: list[Any] = [settings, cand.units, cand.up_axis, cand.units_reason]
        if cand.metadata.get("size") is not None:  # a stated size decides the facts (mixcount.sizes.decide_size)
            frame.append({"size": cand.metadata["size"]})
        if cand.up_axis and cand.model_path.suffix.lower() in GLTF_EXTENSIONS:
            frame.append("gltf up axis as stated")  # once ignored: such objects are measured again
        folder = cand.model_path.resolve().parent
        if any(folder not in Path(v).resolve().parents for v in resources.values()):
            frame.append("files outside the model's folder read")  # once dropped (frame.load_model): measured again
        prep.settings_hash = hashing.json_hash(frame)
        prep.ingest_hash = hashing.combine([
            ("content", prep.content_hash), ("sidecars", sidecar_hash), ("identity", identity_hash),
            ("settings", prep.settings_hash),
        ])
    except IngestError as exc:
        prep.error = exc.reason
    except OSError as exc:
        prep.error = f"unreadable file: {exc.strerror or exc}"
    return prep


# --------------------------------------------------------------------------- storing


def _ingest_info(obj: CatalogObject) -> dict[str, Any]:
    try:
        data = json.loads(obj.metadata_json or "{}")
    except ValueError:
        return {}
    info = data.get("ingest") if isinstance(data, dict) else None
    return info if isinstance(info, dict) else {}


def _get(session: Session, cand: Candidate) -> CatalogObject | None:
    return session.scalars(
        select(CatalogObject).where(CatalogObject.source == cand.source, CatalogObject.source_id == cand.source_id)
    ).one_or_none()


def _existing_rows(session: Session, candidates: list[Candidate]) -> dict[tuple[str, str], CatalogObject]:
    """The stored rows of these candidates, in a few queries (one per 500 ids) rather than one each."""
    wanted = {(c.source, c.source_id) for c in candidates}
    ids = sorted({c.source_id for c in candidates})
    rows: dict[tuple[str, str], CatalogObject] = {}
    for start in range(0, len(ids), 500):
        chunk = ids[start:start + 500]
        for obj in session.scalars(select(CatalogObject).where(CatalogObject.source_id.in_(chunk))):
            if (obj.source, obj.source_id) in wanted:
                rows[(obj.source, obj.source_id)] = obj
    return rows


def _stored_path(path: Path) -> str:
    """The model path as stored: absolute, but a staged link stays the link (its folder holds the
    files the loaders need beside the model)."""
    return os.path.abspath(path)


def _apply_identity(obj: CatalogObject, prep: Prepared, run_id: int | None, ingest: dict[str, Any]) -> None:
    cand = prep.cand
    obj.name = cand.name
    obj.category = cand.category
    obj.model_path = safe_text(_stored_path(cand.model_path)) if cand.model_path else ""
    obj.license = cand.license
    obj.metadata_json = json.dumps({"metadata": cand.metadata, "ingest": ingest}, sort_keys=True, default=str)
    obj.ingest_run_id = run_id
    obj.updated_at = utcnow()


def _same_identity(obj: CatalogObject, cand: Candidate) -> bool:
    return obj.name == cand.name and obj.category == cand.category


def _store(
    session: Session, prep: Prepared, facts: dict[str, Any] | None, error: str | None, run_id: int | None,
    ctx: StoreContext | None = None,
) -> str:
    """Insert or update one object and commit; returns new | updated | unchanged | broken. An update that
    changes what later steps derived from the object removes those (:mod:`mixcount.catalog.stale`) and
    a changed up axis is reported in ``ctx.summary``."""
    cand = prep.cand
    for attempt in range(2):
        obj = _get(session, cand)
        is_new = obj is None
        if obj is None:
            obj = CatalogObject(source=cand.source, source_id=cand.source_id)
            session.add(obj)
        before = Before.of(obj)
        was_active = not is_new and obj.status != STATUS_BROKEN
        if error:
            if not is_new and obj.status == STATUS_BROKEN and obj.error == error and _same_identity(obj, cand):
                session.rollback()
                return "broken"
            ingest = {"ingest_hash": prep.ingest_hash, "layout": cand.layout}
            _apply_identity(obj, prep, run_id, ingest)
            obj.content_hash = prep.content_hash
            obj.status = STATUS_BROKEN
            obj.error = error
            outcome = "broken"
        else:
            assert facts is not None
            note = facts.get("facts_note")  # a big mesh analysed on a copy, numerical warnings: said and kept
            if note and note not in cand.warnings:
                cand.warnings.append(note)
            ingest = {
                "ingest_hash": prep.ingest_hash,
                "layout": cand.layout,
                "settings_hash": prep.settings_hash,
                "appearance": facts.get("appearance"),
                "n_parts": facts.get("n_parts"),
                "sidecars": sorted(cand.sidecars),
                "up_axis_reason": cand.up_reason,
                "units_reason": facts.get("units_reason") or cand.units_reason,
                "parts_rule": cand.parts_rule,
                "warnings": list(cand.warnings),
                "collision_source": facts.get("collision_source"),
                "facts_note": note,
            }
            _apply_identity(obj, prep, run_id, ingest)
            obj.content_hash = prep.content_hash
            for key in FACT_FIELDS:
                setattr(obj, key, facts[key])
            obj.status = STATUS_EXCLUDED if obj.status == STATUS_EXCLUDED else STATUS_ACTIVE
            obj.error = None
            outcome = "new" if is_new else "updated"
            if ctx is not None:
                ctx.summary.note_units(obj.name, obj.source_units, ingest["units_reason"])
        if was_active and ctx is not None:
            changed = before.changed(obj)
            if changed:
                session.flush()
                invalidate(session, obj, before, renders_dir=ctx.renders_dir, descriptors_dir=ctx.descriptors_dir)
                ctx.summary.invalidated.append((obj.name, changed))
            old_up, new_up = before.get("source_up_axis"), obj.source_up_axis
            if not error and old_up and new_up and old_up != new_up:
                ctx.summary.reoriented.append((obj.name, str(old_up), str(new_up), cand.up_reason or ""))
        if not error:
            session.flush()
            write_warning_flags(session, obj, cand.warnings)
        try:
            session.commit()
            return outcome
        except IntegrityError:  # another ingest inserted the same (source, source_id) meanwhile
            session.rollback()
            if attempt:
                raise
    raise AssertionError("unreachable")


def _facts_of(obj: CatalogObject) -> dict[str, Any]:
    facts = {key: getattr(obj, key) for key in FACT_FIELDS}
    info = _ingest_info(obj)
    facts["appearance"] = info.get("appearance")
    facts["n_parts"] = info.get("n_parts")
    facts["collision_source"] = info.get("collision_source")
    facts["units_reason"] = info.get("units_reason")
    facts["facts_note"] = info.get("facts_note")
    return facts


# --------------------------------------------------------------------------- the run


def ingest_paths(
    catalog: Any,
    paths: Iterable[Path | str],
    *,
    config: Config,
    progress: ProgressReporter | bool | None = None,
    strict: bool = False,
    layout: str = "auto",
    metadata_files: Iterable[Path | str] = (),
    up_axis: str | None = None,
    units: str | None = None,
    parts: str = "auto",
    allow_roots: Iterable[Path | str] = (),
    size_of: Iterable[str] = (),
) -> IngestSummary:
    """Ingest every object under ``paths`` into ``catalog``; see the module docstring.

    ``layout`` forces one library layout (``auto`` detects it per folder); ``metadata_files`` are side
    metadata files (JSON/JSONL/CSV) searched for every model's id. ``strict`` does not change what is
    stored; the CLI uses it to exit non-zero when anything is broken. ``up_axis`` (X, Y or Z; None or
    ``auto``: each file's own rule) is the up axis of every object whose metadata or layout states none,
    glTF included (docs/ingest.md, "Units and up axis"). ``units`` (``--units``) and ``parts`` (``--parts``):
    :mod:`mixcount.catalog.units`, :mod:`mixcount.catalog.layouts.parts`. ``allow_roots`` (``--allow-root``)
    and ``ingest.extra_roots`` widen each library's boundary (:mod:`mixcount.library_root`). ``size_of``
    (``--size-of FOLDER=SIZE``): the real size of every object under a folder whose metadata states none
    (:func:`mixcount.catalog.typical_sizes.apply_size_of`).
    """
    paths = list(paths)
    refused: list[tuple[Path, str]] = []
    extra = [*config.ingest.extra_roots, *allow_roots]
    candidates = _discover(catalog, paths, config.ingest, layout=layout, metadata_files=metadata_files,
                           up_axis=up_axis, units=units, parts=parts, extra_roots=extra, refused=refused)
    apply_size_of(candidates, list(size_of))  # a size stated for whole folders (issue 70)
    run = _start_run(catalog, paths, candidates, config.ingest)
    run.summary.refused = [(safe_text(str(p)), safe_text(r)) for p, r in refused]
    bar = as_reporter(progress)
    status = "interrupted"
    try:
        bar.start("ingest", len(candidates))
        with catalog.session() as session:
            known = _existing_rows(session, candidates)
            pending: list[Prepared] = []
            for cand in candidates:
                prep = _triage(session, run, cand, known.get((cand.source, cand.source_id)))
                if prep is None:
                    bar.advance()
                else:
                    pending.append(prep)
            run.decoded.save()
            if pending:
                _analyse_all(session, pending, run, run.workers, run.count, bar)
            _turn_containers(session, run, candidates, known, config)
        status = "done"
    finally:
        bar.stop()
        _finish_run(catalog, run.summary, status)
    return run.summary


@dataclass
class _Run:
    """What the steps of one ingest run share: its summary and store context, and the settings."""

    summary: IngestSummary
    ctx: StoreContext
    settings: dict[str, Any]
    max_bytes: float
    max_vertices: int
    workers: int
    collision_dir: Path
    max_pixels: int
    decoded: DecodedFiles  # texture files this catalog already decoded whole (media_check)

    def count(self, outcome: str, prep: Prepared, error: str | None = None) -> None:
        summary = self.summary
        setattr(summary, outcome, getattr(summary, outcome) + 1)
        if outcome == "broken":
            summary.broken_objects.append((prep.cand.name, error or prep.error or ""))
            if error and run_failure(error):
                summary.failed.append((prep.cand.name, error))
        else:
            summary.warnings.extend((prep.cand.name, w) for w in prep.cand.warnings)

    def prepare(self, cand: Candidate) -> Prepared:
        return prepare(cand, settings=self.settings, max_bytes=self.max_bytes, max_pixels=self.max_pixels,
                       decoded=self.decoded)


def _discover(catalog: Any, paths: list[Path | str], ing: IngestConfig, *, layout: str,
              metadata_files: Iterable[Path | str], up_axis: str | None, units: str | None,
              parts: str, extra_roots: list[str | Path] | None = None,
              refused: list[tuple[Path, str]] | None = None) -> list[Candidate]:
    """Step 1: every object under ``paths``, oriented, staged, its unit decided and derived models made."""
    stated_units = check_units(units)
    candidates = discover(paths, layout=layout, metadata_files=metadata_files, parts=check_parts(parts),
                          allowed=extra_roots or [], refused=refused)
    for cand in candidates:
        if cand.layout == SOURCE_OMNI:  # OBJ scans without units: the configured convention of the layout
            cand.units = cand.units or ing.omniobject3d_units
            if not cand.up_axis:
                cand.up_axis, cand.up_reason = ing.omniobject3d_up_axis, "ingest.omniobject3d_up_axis"
    with catalog.session() as session:
        orient(session, candidates, paths, up_axis, assume=ing.assume_up_axis)
    for cand in candidates:
        # every model read here (a part, a STEP) reads no reference outside the object's library
        with bounded(cand.roots) if cand.roots is not None else nullcontext():
            layouts.stage(cand, catalog.staged_dir)
            decide_frame(cand, stated=stated_units, assume=ing.assume_units)  # the unit and why (mixcount.catalog.units)
            with quiet_native_output():  # OpenCASCADE's own complaints: the broken reason says it in one line
                derive(cand, catalog.staged_dir)  # STEP or parts: one GLB in the sources' numbers
    return candidates


def _start_run(catalog: Any, paths: list[Path | str], candidates: list[Candidate], ing: IngestConfig) -> _Run:
    """The run's settings and summary (objects found per layout), and its IngestRun row (status running)."""
    summary = IngestSummary()
    for cand in candidates:
        summary.layouts[cand.layout] = summary.layouts.get(cand.layout, 0) + 1
    run = _Run(summary, StoreContext(summary, catalog.renders_dir, catalog.data_dir / "descriptors"),
               settings_of(ing), ing.max_file_mb * 2**20, proxy_budget(ing), max(1, ing.workers),
               catalog.collision_dir, ing.max_image_pixels, DecodedFiles(catalog.data_dir / DECODED_FILES))
    with catalog.session() as session:
        summary.interrupted_runs = close_interrupted_runs(session, catalog.data_dir)
        row = IngestRun(paths=json.dumps([str(p) for p in paths]), status="running")
        session.add(row)
        session.flush()
        summary.run_id = row.id
        note_running(catalog.data_dir, row.id)  # before the row is seen: a run beside it never closes it
        session.commit()
    for cand in candidates:
        for key in cand.ignored:
            summary.ignored[key] = summary.ignored.get(key, 0) + 1
    return run


def _triage(session: Session, run: _Run, cand: Candidate, existing: CatalogObject | None) -> Prepared | None:
    """Step 2 for one candidate: pre-checked and hashed; a broken, unchanged or metadata-only object is
    counted (and stored) here and None returned; the Prepared returned needs the mesh analysis."""
    if existing is not None:
        kept_evidence(cand, existing.source_up_axis, _ingest_info(existing).get("up_axis_reason"))
    prep = run.prepare(cand)
    if prep.error:
        if (existing is not None and existing.status == STATUS_BROKEN and existing.error == prep.error
                and _same_identity(existing, cand)):
            run.count("broken", prep)  # still broken the same way, same name: nothing to write
        else:
            run.count(_store(session, prep, None, prep.error, run.summary.run_id, run.ctx), prep)
        return None
    if existing is None or existing.status == STATUS_BROKEN:
        return prep
    info = _ingest_info(existing)
    same_path = existing.model_path == _stored_path(cand.model_path)  # type: ignore[arg-type]
    if info.get("ingest_hash") == prep.ingest_hash and same_path:
        refresh_proxy(session, existing, run.collision_dir, run.max_vertices)
        run.summary.note_units(existing.name, existing.source_units, info.get("units_reason"))
        run.count("unchanged", prep)
        return None
    if (
        existing.content_hash == prep.content_hash
        and info.get("settings_hash") == prep.settings_hash
        and existing.geometry_hash
        and Path(existing.collision_path or "").is_file()
    ):
        # only sidecars or the location changed: keep the measured facts
        refresh_proxy(session, existing, run.collision_dir, run.max_vertices)
        run.count(_store(session, prep, _facts_of(existing), None, run.summary.run_id, run.ctx), prep)
        return None
    return prep


def _turn_containers(session: Session, run: _Run, candidates: list[Candidate],
                     known: dict[tuple[str, str], CatalogObject], config: Config) -> None:
    """Step 5: the catalog's containers; those read by ``ingest.assume_up_axis`` whose opening faces another
    axis of the file are turned and analysed again (:func:`mixcount.catalog.orientation.turn_by_openings`)."""
    summary = run.summary
    summary.containers = refresh_containers(session, config).containers
    turned = turn_by_openings(session, candidates, assume=config.ingest.assume_up_axis)
    if turned:
        fresh = {c.name for c in turned if (c.source, c.source_id) not in known}
        mark = len(summary.invalidated)
        again = [run.prepare(c) for c in turned]
        _analyse_all(session, again, run, 1, lambda *_a, **_k: None, as_reporter(None))
        summary.invalidated[mark:] = [e for e in summary.invalidated[mark:] if e[0] not in fresh]
        summary.containers = refresh_containers(session, config).containers
    summary.container_warnings = opening_warnings(session)


def _finish_run(catalog: Any, summary: IngestSummary, status: str) -> None:
    """The IngestRun row closed with its status (done or interrupted) and counts."""
    with catalog.session() as session:
        row = session.get(IngestRun, summary.run_id)
        if row is not None:
            row.status = status
            row.finished_at = utcnow()
            row.n_new, row.n_unchanged = summary.new, summary.unchanged
            row.n_updated, row.n_broken = summary.updated, summary.broken
            session.commit()
    done_running(catalog.data_dir, summary.run_id)


def _analyse_all(session: Session, pending: list[Prepared], run: _Run, n_workers: int,
                 count: Callable[..., None], bar: ProgressReporter) -> None:
    """Step 3 and 4: the mesh analysis of ``pending`` (:mod:`mixcount.catalog.analysis_pool`), each object
    stored and counted as its analysis finishes."""

    def finish(prep: Prepared, facts: dict[str, Any] | None, error: str | None) -> None:
        outcome = _store(session, prep, facts, error, run.summary.run_id, run.ctx)
        count(outcome, prep, error)
        bar.advance(info=prep.cand.name[:40])

    settings = {**run.settings, "proxy_max_vertices": run.max_vertices}
    analyse_all([(p, analysis_kwargs(p.cand, run.collision_dir, settings)) for p in pending], n_workers, finish)
