"""Which catalog objects are containers (plates, trays, bowls, ...) the scenes drop counted objects into.

An object is a container when, in this order:

1. a person decided it (the latest ``container`` / ``not_container`` review decision) - that outranks
   every rule;
2. its category is one of ``[containers] categories`` (or the category's last word is: "dinner plate");
3. a word of its name, of the name in its metadata (DTC ``metadata.json``, GSO ``metadata.pbtxt``, an
   Objaverse record) or of its active short / concise caption is one of ``[containers] keywords``
   (compared singular and lower case: "Serving_Platter_02" and "two bowls" match).

:func:`refresh_containers` stores the answer in ``objects.container`` with a one-line reason in
``objects.container_reason``; ingest, captioning and ``catalog filter`` call it, so the stored value
follows new names, captions, rules and decisions. The sampler reads only the stored column.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Optional

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.decisions import CONTAINER_DECISIONS, latest_container_decisions
from mixcount.catalog.models import STATUS_ACTIVE, CaptionSet, CatalogObject
from mixcount.catalog.naming import singular
from mixcount.config import Config
from mixcount.scene.words import words_of

CONFIG_KEYS = "containers.categories / containers.keywords"


@dataclass(frozen=True)
class ContainerRules:
    """The ``[containers]`` section: category names and name/caption keywords (singular, lower case)."""

    categories: frozenset[str]
    keywords: frozenset[str]

    @classmethod
    def from_config(cls, cfg: Config) -> "ContainerRules":
        section = cfg.containers
        return cls(frozenset(singular(str(c)) for c in section.categories),
                   frozenset(singular(str(k)) for k in section.keywords))


@dataclass
class ContainerSummary:
    containers: int = 0
    changed: int = 0
    by_review: int = 0
    names: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {"containers": self.containers, "changed": self.changed, "by_review": self.by_review}


def _metadata_names(obj: CatalogObject) -> list[str]:
    try:
        data = json.loads(obj.metadata_json or "{}")
    except ValueError:
        return []
    meta = data.get("metadata") if isinstance(data, dict) else None
    if not isinstance(meta, dict):
        return []
    out = [meta.get(k) for k in ("name", "title")]
    record = meta.get("record")
    if isinstance(record, dict):
        out += [record.get(k) for k in ("name", "title")]
    return [v for v in out if isinstance(v, str)]


def rule_reason(rules: ContainerRules, *, category: str, texts: Iterable[tuple[str, str]]) -> str | None:
    """Why the rules make an object a container (``texts``: (where, text) pairs), or None."""
    cat = singular(category or "")
    if cat and (cat in rules.categories or cat.split()[-1] in rules.categories):
        return f"category {cat!r} is in containers.categories"
    for where, text in texts:
        for word in words_of(text or ""):
            if singular(word) in rules.keywords:
                return f"{where} {text!r} has the keyword {singular(word)!r} (containers.keywords)"
    return None


def refresh_containers(session: Session, config: Config, *, commit: bool = True) -> ContainerSummary:
    """Recompute ``container`` / ``container_reason`` of every object (reviews first, then the rules)."""
    rules = ContainerRules.from_config(config)
    decisions = latest_container_decisions(session)
    captions: dict[int, CaptionSet] = {}
    for cs in session.scalars(select(CaptionSet).where(CaptionSet.active.is_(True)).order_by(CaptionSet.id)):
        captions[cs.object_id] = cs
    summary = ContainerSummary()
    for obj in session.scalars(select(CatalogObject).order_by(CatalogObject.id)):
        rd = decisions.get(obj.id)
        if rd is not None:
            value = CONTAINER_DECISIONS[rd.decision]
            reason = f"review: {rd.decision} by {rd.reviewer or 'someone'} at {rd.decided_at.isoformat()}Z"
            summary.by_review += 1
        else:
            texts = [("name", obj.name)] + [("metadata name", n) for n in _metadata_names(obj)]
            cs = captions.get(obj.id)
            if cs is not None:
                texts += [("caption", cs.short), ("caption", cs.concise)]
            reason = rule_reason(rules, category=obj.category, texts=texts)
            value = reason is not None
        if bool(obj.container) != value or obj.container_reason != reason:
            obj.container, obj.container_reason = value, reason
            summary.changed += 1
        if value:
            summary.containers += 1
            summary.names.append(obj.name)
    if commit:
        session.commit()
    return summary


# ------------------------------------------------------------------------------ which way the opening faces

OPENING_MIN_DEPTH = 0.03  # of the object's largest side: a hull point this far from the surface is over a cavity
OPENING_UP_MIN_Z = 0.7  # cosine: an opening more than ~45 degrees from +Z does not face up
OPENING_SAMPLES = 3000  # points on the hull and on the surface (seeded: the same answer every run)


def opening_direction(collision_path: str | Path) -> Optional[np.ndarray]:
    """Unit vector (metres, Z-up frame of the catalog) the opening of a container's mesh faces, or None
    when it has no clear opening (a closed box, a flat board).

    Points spread evenly over the mesh's convex hull that lie far from the mesh's own surface are over
    its cavity (the lid a bowl lacks); the mean hull normal at those points, weighted by how far they lie
    from the surface, points out of the opening. Uses the stored collision mesh (decimated, same frame
    as the render asset), so it reads nothing but that file."""
    import trimesh
    from scipy.spatial import cKDTree

    mesh = trimesh.load(str(collision_path), force="mesh", process=False)
    if len(mesh.faces) < 4:
        return None
    size = float(np.max(mesh.extents))
    if not size > 0:
        return None
    hull = mesh.convex_hull
    rng = np.random.default_rng(0)
    surface = np.asarray(trimesh.sample.sample_surface(mesh, OPENING_SAMPLES * 4, seed=rng)[0])
    points, faces = trimesh.sample.sample_surface(hull, OPENING_SAMPLES, seed=rng)
    dist = cKDTree(np.vstack([surface, np.asarray(mesh.vertices)])).query(np.asarray(points))[0] / size
    far = dist > OPENING_MIN_DEPTH
    if far.mean() < 0.02:  # almost the whole hull lies on the surface: no cavity worth the name
        return None
    vec = (np.asarray(hull.face_normals)[faces[far]] * dist[far, None]).sum(axis=0)
    norm = float(np.linalg.norm(vec))
    if norm < 1e-9 or norm < 0.3 * float(dist[far].sum()):  # openings on several sides: no one direction
        return None
    return np.asarray(vec / norm)


def _direction_words(vec: np.ndarray) -> str:
    axis = int(np.argmax(np.abs(vec)))
    return f"{'+' if vec[axis] > 0 else '-'}{'XYZ'[axis]}"


def opening_warnings(session: Session) -> list[str]:
    """One line per active container whose opening does not face up (+Z): its up axis was probably read
    wrongly (a Z-up model in a GLB is read Y-up by glTF's rule), so scenes would drop objects onto its
    side. The line says how to state the axis. Containers without a collision mesh or a clear opening
    are not judged."""
    lines = []
    query = select(CatalogObject).where(CatalogObject.container.is_(True), CatalogObject.status == STATUS_ACTIVE)
    for obj in session.scalars(query.order_by(CatalogObject.id)):
        if not obj.collision_path or not Path(obj.collision_path).is_file():
            continue
        try:
            vec = opening_direction(obj.collision_path)
        except Exception:  # an unreadable collision mesh is reported elsewhere; this check only warns
            continue
        if vec is None or vec[2] >= OPENING_UP_MIN_Z:
            continue
        lines.append(
            f"container #{obj.id} {obj.name!r}: its opening faces {_direction_words(vec)}, not up (+Z), read with "
            f"up axis {obj.source_up_axis or '?'}; if its up axis is another, say so (\"up_axis\": \"Z\" in its "
            "metadata.json, or catalog ingest --up-axis Z) and ingest again")
    return lines
