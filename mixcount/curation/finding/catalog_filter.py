"""`catalog filter`: duplicate and quality flags, one kept object per duplicate group, review outranks all.

Flags (each with a score in [0, 1], a reason, and the paired object where it is a pairing; pairs are
flagged in both directions). Thresholds are the ``[filter]`` section; descriptors in
:mod:`mixcount.curation.finding.descriptors`; the rationale is in docs/curation.md.

* ``exact_duplicate``: identical model content (content hash), or the identical mesh (geometry hash) with
  indistinguishable canonical renders.
* ``near_duplicate_geometry``: the same shape (D2 distance and principal-extent proportions under their
  thresholds) at the same size, with the same texture layout (edge structure of the renders) *and* the
  same colours (renders or surface): a copy. Shape alone is not enough: every sphere has the same shape.
* ``colour_variant``: the same test with other colours: one object in two colours (a recolour, another
  print of one mould). Not a duplicate: both stay active, the pair is a hard pair of classes for the
  sampler and the pair shares one split. Flagged in both directions with the figures.
* ``near_duplicate_appearance``: the same look, two ways. (a) Canonical renders that look alike (pHash
  and colour histogram): renders are framed scale-free, so a rescaled copy lands here. (b) Whatever the
  orientation: the same surface colours and the same colour layout in the principal frame
  (:mod:`mixcount.curation.finding.appearance3d`), *and* the same shape at any scale (D2 and second-moment
  proportions): a copy turned over (another up axis), rescaled, re-tessellated or re-exported by another
  source lands here. (c) A copy from another source whose shape agrees only loosely (decimated to a few
  per cent of its faces, flattened by a re-export: ``cross_source_*``) with the same surface colours and
  layout on a *patterned* surface.
* ``possible_copy``: the evidence is not sure: a loosely agreeing shape with the same *plain* colour,
  where the layout has no pattern to confirm it (rule (c) on a plain surface); a loosely agreeing shape
  in other colours whose colour pattern repeats; or, on two plain surfaces in other colours, the same
  shape once each principal axis is scaled to its extent (a re-export's squash taken out), for shapes
  mirror-asymmetric along two principal axes (:func:`_plain_recoloured_copy`; ``colour_variant`` there
  when the shape also agrees tightly). Flagged for a person (``catalog sheet --only flagged``), never
  excluded or merged.
* ``degenerate`` means unusable: unreadable (broken) files, too few faces, (near) zero area, zero volume
  although closed, flat beyond repair (thickness below 1/``max_aspect_ratio`` of the length, along the
  principal axes), a blank render.
* ``mesh_quality`` is a warning with a score: non-manifold edges, holes (open edges), self-intersecting
  faces. Such meshes render, and physics uses convex hulls, so it never excludes unless
  ``filter.exclude_mesh_quality`` is set.
* ``size_outlier``: outside the absolute size bounds, or far from its category's median size.
* ``caption_collision`` belongs to captioning (:mod:`mixcount.captions.captioning`) and is left alone.

Statuses: each connected group of duplicate pairs keeps one object, the first in the *quality order*
(a person accepted it; fewer quality flags, mesh_quality included; image texture > vertex colours > plain material > none; more
faces; lower id), and the other members become ``excluded``; degenerate objects are excluded too when
``filter.exclude_degenerate``. Nothing is deleted. A person's latest review decision outranks all of it
(accept -> active, reject -> excluded) and is re-applied on every run. Re-running is idempotent: the
filter deletes and recomputes only its own flag kinds and first re-activates only the objects it had
excluded itself (their flag reason carries :data:`EXCLUDED_MARK`).
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from mixcount.catalog.containers import refresh_containers
from mixcount.catalog.db import Catalog
from mixcount.catalog.decisions import latest_decisions, latest_pair_decisions
from mixcount.catalog.grouping import connected_groups
from mixcount.catalog.models import (
    STATUS_ACTIVE,
    STATUS_BROKEN,
    STATUS_EXCLUDED,
    CatalogObject,
    Flag,
)
from mixcount.catalog.records import ingest_appearance
from mixcount.config import Config
from mixcount.curation.finding import appearance3d as A
from mixcount.curation.finding import colour_layout as CL
from mixcount.curation.finding import descriptors as D
from mixcount.curation.finding import pair_evidence as E
from mixcount.curation.finding.candidates import candidate_pairs, queries
from mixcount.curation.finding.copy_rules import pair_flags, shape_gate
from mixcount.curation.finding.filter_items import Found, Item, LayoutCache, object_label
from mixcount.curation.finding.ground_truth import evaluate_against_ground_truth
from mixcount.curation.finding.quality_flags import quality_flags
from mixcount.curation.flag_kinds import (
    APPEARANCE_RANK,
    DECIDE,
    DEGENERATE,
    DUPLICATE_KINDS,
    EXCLUDED_MARK,
    FILTER_KINDS,
    MESH_QUALITY,
    POSSIBLE_COPY,
    QUALITY_KINDS,
    decided_mark,
    severity,
)
from mixcount.curation.renders import canonical_render_path, mask_path_for
from mixcount.progress import ProgressReporter, as_reporter
from mixcount.threads import one_blas_thread


@dataclass
class FilterSummary:
    objects: int = 0
    flags: dict[str, int] = field(default_factory=dict)
    groups: int = 0
    excluded: int = 0
    reactivated: int = 0
    review_applied: int = 0
    missing_renders: int = 0
    candidate_pairs: int = 0
    to_decide_objects: int = 0  # objects with a flag of severity decide (`catalog sheet --only flagged`)
    to_decide_pairs: int = 0
    containers: int = 0
    descriptor_failures: list[dict[str, Any]] = field(default_factory=list)
    ground_truth: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)



def _describe(catalog: Catalog, session: Session, items: list[Item], summary: FilterSummary,
              cluster: Any, progress: ProgressReporter | None = None) -> None:
    """Each item's descriptors (:func:`describe_one`) as tasks of ``cluster`` (:func:`filter_executor`: a
    Ray cluster under ``--executor ray``, ``[filter] workers`` local processes, or this process), whose
    results are set here in the items' order."""
    from mixcount.catalog.step_executor import TaskFailed

    cache = str(catalog.data_dir / "descriptors")
    work = []
    for it in items:
        obj = it.obj
        it.appearance = ingest_appearance(obj)
        path = canonical_render_path(session, obj.id)
        work.append((obj.model_path, obj.source_units, obj.source_up_axis, cache, (obj.geometry_hash or "")[:32] or None,
                     (obj.content_hash or "")[:32] or None, str(path) if path is not None else None))
    described = cluster.map(describe_one, work)
    bar = as_reporter(progress)
    bar.start("filter: descriptors", len(items))
    for it, got in zip(items, described):
        bar.advance()
        obj = it.obj
        if isinstance(got, TaskFailed):
            summary.descriptor_failures.append({"id": obj.id, "name": obj.name, "error": got.error})
            continue
        it.shape, it.surface, it.look, errors, missing = got
        summary.missing_renders += int(missing)
        summary.descriptor_failures.extend({"id": obj.id, "name": obj.name, "error": e} for e in errors)
    bar.stop()


def describe_one(model_path: str, units: str | None, up_axis: str | None, cache_dir: str, shape_key: str | None,
                 surface_key: str | None, render: str | None) -> tuple[Any, Any, Any, list[str], bool]:
    """One object's (shape, surface look, render look, errors, render missing): what the filter knows of it
    alone. Each failing descriptor is one error line and None (a model that ingested but no longer loads:
    reported, the batch goes on). A Ray task under ``--executor ray``."""
    cache = Path(cache_dir)
    shape = surface = look = None
    errors: list[str] = []
    try:
        shape = D.load_shape(model_path, units=units, up_axis=up_axis, cache_dir=cache, key=shape_key)
    except Exception as exc:  # noqa: BLE001
        errors.append(f"{type(exc).__name__}: {exc}")
    try:
        points, colours = A.load_samples(model_path, cache_dir=cache, key=surface_key)
        surface = A.surface_look(points, colours)
    except Exception as exc:  # noqa: BLE001 - as above
        errors.append(f"surface appearance: {type(exc).__name__}: {exc}")
    if render is None:
        return shape, surface, look, errors, True
    try:
        look = D.appearance_descriptor(Path(render), mask_path_for(render))
    except OSError as exc:
        errors.append(f"render unreadable: {exc}")
    return shape, surface, look, errors, False


PAIRS_PER_TASK = 200  # at most this many pairs in one pair-figures task, at most OBJECTS_PER_TASK objects in
OBJECTS_PER_TASK = 50  # one primitive-fits task: progress moves, and a lost task (a node killed) costs little
SAVE_EVERY_S = 60.0  # the pair-figure cache is written this often while the figures come in


def _chunk_size(n: int, cpus: int, most: int) -> int:
    """Tasks of about a quarter of ``n`` per CPU (so the cluster's CPUs stay busy to the end), at most ``most``."""
    return max(1, min(most, n // (4 * max(1, cpus))))


def figures_in_parallel(cluster: Any, th: Any, layouts: LayoutCache, compare: list[tuple[Item, Item]],
                        progress: ProgressReporter | None = None) -> None:
    """The pair rules' costly figures (alignments, primitive fits, layout distances: what
    :class:`LayoutCache` keeps) of ``compare`` computed as tasks of ``cluster`` (Ray, local processes or
    this process: :func:`filter_executor`), a chunk of pairs each, and merged into ``layouts``; the rules then
    run here on the filled cache, so the flags are those of one process."""
    from mixcount.catalog.step_executor import TaskFailed, chunks

    if not compare:
        return
    bar = as_reporter(progress)
    saved_at = time.monotonic()

    def merge(got: Any) -> None:
        """A task's figures into the cache, saved every SAVE_EVERY_S: a filter stopped or killed after
        an hour of alignments goes on from what it had (the rerun's tasks find those figures known)."""
        nonlocal saved_at
        if isinstance(got, TaskFailed) or not got:  # a lost chunk: its pairs are computed here by the rules
            return
        layouts.values.update(got)
        layouts.dirty = True
        if time.monotonic() - saved_at >= SAVE_EVERY_S:
            layouts.save()
            saved_at = time.monotonic()

    def phase(label: str, fn: Any, work: list[Any], most: int) -> None:
        """``fn`` over ``work`` in tasks of at most ``most`` items, the figures known so far shared."""
        shared = cluster.put(dict(layouts.values))
        parts = chunks(work, _chunk_size(len(work), cluster.cpus(), most))
        bar.start(label, len(work))
        for part, got in zip(parts, cluster.map(fn, [(p, th, shared) for p in parts])):
            bar.advance(len(part))
            merge(got)
        bar.stop()

    try:
        # each object's primitive distance once, first: a chunk of pairs would otherwise fit the primitives
        # of every object it holds again (an object sits in ~2k candidate pairs, spread over the chunks)
        gated = sorted({id(it): it for p in compare if shape_gate(p[0], p[1], th) for it in p}.values(),
                       key=lambda it: it.obj.id)
        if gated:
            phase("filter: primitive fits", primitive_figures, gated, OBJECTS_PER_TASK)
        phase("filter: pair figures", pair_figures, compare, PAIRS_PER_TASK)
    finally:
        layouts.save()  # also on Ctrl-C or an error: what was computed is kept


def primitive_figures(items: list[Item], th: Any, known: dict[str, float]) -> dict[str, float]:
    """A task (Ray or a local process): the primitive distances of ``items`` that ``known`` lacks."""
    cache = LayoutCache(None)
    cache.values = dict(known)
    for it in items:
        E.primitive(it, th, cache)
    return {k: v for k, v in cache.values.items() if k not in known}


def pair_figures(pairs: list[tuple[Item, Item]], th: Any, known: dict[str, float]) -> dict[str, float]:
    """A task (Ray or a local process): the :class:`LayoutCache` values the pair rules compute for ``pairs`` and ``known`` lacks."""
    cache = LayoutCache(None)
    cache.values = dict(known)
    pair_flags([it for p in pairs for it in p], th, cache, pairs)
    return {k: v for k, v in cache.values.items() if k not in known}


def candidate_items(items: list[Item], k: int) -> list[tuple[Item, Item]]:
    """The pairs the pair rules look at (:mod:`mixcount.curation.finding.candidates`): each object's ``k``
    nearest in the descriptor index, objects sharing a hash, and every pair with an object whose
    surface samples are missing (nothing to index it by)."""
    indexed = [it for it in items if it.surface is not None]
    rest = [it for it in items if it.surface is None]
    asks = np.asarray([queries(it.surface.points, it.surface.colours) for it in indexed])  # type: ignore[union-attr]
    hashes = [(it.obj.content_hash, it.obj.geometry_hash) for it in indexed]
    pairs = ([(indexed[i], indexed[j]) for i, j in candidate_pairs(asks[:, 0], k=k, hashes=hashes, extra=asks[:, 1:])]
             if indexed else [])
    has_surface = {it.obj.id for it in indexed}
    pairs += [(x, y) for x in rest for y in items
              if y is not x and (y.obj.id in has_surface or x.obj.id < y.obj.id)]
    return pairs


def quality_key(obj: CatalogObject, *, accepted: set[int], quality_flags: dict[int, int], appearance: str) -> tuple:
    """Sort key of the documented quality order: smaller is better."""
    return (
        0 if obj.id in accepted else 1,
        quality_flags.get(obj.id, 0),
        APPEARANCE_RANK.get(appearance, 3),
        -(obj.face_count or 0),
        obj.id,
    )


def _groups(pairs: Iterable[tuple[int, int]]) -> list[list[int]]:
    return connected_groups(pairs)


@contextmanager
def filter_executor(th: Any) -> Iterator[Any]:
    """Where the filter's per-object descriptors and per-pair figures run: the Ray cluster of the command
    (``--executor ray``), else ``[filter] workers`` forked processes of this machine
    (:class:`mixcount.catalog.step_executor.LocalProcesses`; before issue 69 the local filter used one
    core of many), else this process one task after the other
    (:class:`mixcount.catalog.step_executor.InThisProcess`): one path for every executor."""
    from mixcount.catalog.step_executor import InThisProcess, LocalProcesses, ray_tasks

    cluster = ray_tasks()
    if cluster is not None:
        yield cluster
        return
    with (LocalProcesses(th.workers) if th.workers > 1 else InThisProcess()) as local:
        yield local


def run_filter(catalog: Catalog, config: Config, *, ground_truth: bool = True,
               progress: ProgressReporter | None = None) -> FilterSummary:
    """Recompute every filter flag, re-pick duplicate keepers, re-apply review decisions (idempotent).

    ``config.filter`` holds the thresholds; ``config.containers`` the container rules recomputed at the end.
    Runs with one BLAS thread (:func:`mixcount.threads.one_blas_thread`: the shape alignment's many tiny
    matrices are several times faster so, with the same results)."""
    with one_blas_thread():
        return _run_filter(catalog, config, ground_truth=ground_truth, progress=progress)


def _run_filter(catalog: Catalog, config: Config, *, ground_truth: bool,
                progress: ProgressReporter | None) -> FilterSummary:
    th = config.filter
    summary = FilterSummary()
    with catalog.session() as session:
        objects = session.scalars(select(CatalogObject).order_by(CatalogObject.id)).all()
        summary.objects = len(objects)
        by_id = {o.id: o for o in objects}
        # 1. undo our own exclusions, then forget our flags (captioning's flags stay)
        ours = session.scalars(select(Flag).where(Flag.kind.in_(FILTER_KINDS))).all()
        marked = {f.object_id for f in ours if EXCLUDED_MARK in (f.reason or "")}
        for oid in marked:
            obj = by_id.get(oid)
            if obj is not None and obj.status == STATUS_EXCLUDED:
                obj.status = STATUS_ACTIVE
                summary.reactivated += 1
        session.execute(delete(Flag).where(Flag.kind.in_(FILTER_KINDS)))
        session.flush()

        live = [o for o in objects if o.status in (STATUS_ACTIVE, STATUS_EXCLUDED)]
        broken = [o for o in objects if o.status == STATUS_BROKEN]
        items = [Item(o) for o in live]
        with filter_executor(th) as cluster:
            _describe(catalog, session, items, summary, cluster, progress)
            layouts = LayoutCache(catalog.data_dir / "descriptors" / f"layouts_{A.APPEARANCE_VERSION}_{CL.LAYOUT_VERSION}.json")
            compare = candidate_items(items, th.candidates)
            summary.candidate_pairs = len(compare)
            figures_in_parallel(cluster, th, layouts, compare, progress)
        item_of = {it.obj.id: it for it in items}
        found = pair_flags(items, th, layouts, compare) + quality_flags(items, broken, th)
        layouts.save()

        decisions = latest_decisions(session)
        accepted = {oid for oid, rd in decisions.items() if rd.decision == "accept"}
        rejected = {oid for oid, rd in decisions.items() if rd.decision == "reject"}
        qflags: dict[int, int] = defaultdict(int)
        for f in found:
            if f.kind in QUALITY_KINDS:
                qflags[f.a] += 1

        # 2. duplicate groups: keep the best active member, exclude the other active ones
        exclude: dict[int, str] = {}
        # a person's pair decisions: "same" joins the two in a group, "variants" / "different" keeps the
        # filter's own pairing of the two from excluding either (the flags stay, marked as decided)
        pair_decisions = {p: rd for p, rd in latest_pair_decisions(session).items() if p <= set(item_of)}
        overruled = {p for p, rd in pair_decisions.items() if rd.decision != "same"}
        flagged_pairs = {frozenset((f.a, f.b)) for f in found if f.b is not None}
        for p, rd in pair_decisions.items():
            if rd.decision == "same" and p not in flagged_pairs:
                a, b = sorted(p)
                found.append(Found(a, b, POSSIBLE_COPY, 1.0, "the same object, by a person's review"))
        pairs = [(f.a, f.b) for f in found if f.b is not None and frozenset((f.a, f.b)) not in overruled
                 and (f.kind in DUPLICATE_KINDS or frozenset((f.a, f.b)) in pair_decisions)]
        for group in _groups(pairs):
            summary.groups += 1
            members = [by_id[i] for i in group]
            candidates = [o for o in members if o.status == STATUS_ACTIVE and o.id not in rejected]
            if not candidates:
                continue
            keep = min(candidates, key=lambda o: quality_key(o, accepted=accepted, quality_flags=qflags,
                                                             appearance=item_of[o.id].appearance))
            for o in candidates:
                if o is not keep and o.id not in accepted:
                    exclude[o.id] = f"{EXCLUDED_MARK} duplicate group keeps {object_label(keep)}"
        for f in found:
            if f.a not in item_of or f.a in accepted or by_id[f.a].status != STATUS_ACTIVE:
                continue
            if f.kind == DEGENERATE and th.exclude_degenerate:
                exclude.setdefault(f.a, f"{EXCLUDED_MARK} degenerate")
            if f.kind == MESH_QUALITY and th.exclude_mesh_quality and f.score >= th.mesh_quality_exclude_score:
                exclude.setdefault(f.a, f"{EXCLUDED_MARK} mesh quality {f.score:.2f}")

        # 3. write flags (both directions for pairs); the excluded side's reasons carry the mark
        counts: dict[str, int] = defaultdict(int)
        decide_objects: set[int] = set()
        decide_pairs: set[frozenset[int]] = set()
        for f in found:
            ends = [(f.a, f.b), (f.b, f.a)] if f.b is not None else [(f.a, None)]
            for oid, other in ends:
                reason = f.reason
                if other is not None:
                    reason = f"{reason}; pair {object_label(by_id[other])}"
                    rd = pair_decisions.get(frozenset((oid, other)))
                    if rd is not None:
                        reason = f"{reason} {decided_mark(rd.decision, rd.reviewer)}"
                if oid in exclude:  # every flag of an excluded object says so: a later run undoes it
                    reason = f"{reason} {exclude[oid]}"
                session.add(Flag(object_id=oid, kind=f.kind, score=float(f.score), reason=reason, pair_object_id=other))
                counts[f.kind] += 1
                if severity(f.kind, reason) == DECIDE:
                    decide_objects.add(oid)
                    if other is not None:
                        decide_pairs.add(frozenset((oid, other)))
        for oid in exclude:
            by_id[oid].status = STATUS_EXCLUDED
        summary.excluded = len(exclude)
        summary.to_decide_objects, summary.to_decide_pairs = len(decide_objects), len(decide_pairs)

        # 4. a person's decision outranks everything
        for oid, rd in decisions.items():
            obj = by_id.get(oid)
            if obj is None or obj.status == STATUS_BROKEN:
                continue
            want = STATUS_ACTIVE if rd.decision == "accept" else STATUS_EXCLUDED
            if obj.status != want:
                obj.status = want
            summary.review_applied += 1
        session.commit()
        summary.flags = {k: counts.get(k, 0) for k in FILTER_KINDS}
        summary.containers = refresh_containers(session, config).containers
    if ground_truth:
        summary.ground_truth = evaluate_against_ground_truth(catalog)
    return summary

