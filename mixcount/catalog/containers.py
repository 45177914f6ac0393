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
from typing import Any, Iterable

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.decisions import CONTAINER_DECISIONS, latest_container_decisions
from mixcount.catalog.models import CaptionSet, CatalogObject
from mixcount.catalog.naming import singular, words_of
from mixcount.config import Config

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
