"""The pair-centred part of the review page (`catalog sheet`): one card per flagged pair, both canonical
renders side by side with the evidence (every flag of the pair with its score and reason, each
object's size, category, status and source) and one click for *same object* / *variants, keep both* /
*different*. Pairs to decide come first (highest score first); then, for information, the look-alikes
(different objects that look alike: the hard pairs a counter must learn, most alike first) and the pairs
a person already decided. The page's script exports the clicks as the decisions file's ``pairs``
(:mod:`mixcount.curation.review.import_decisions`)."""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from sqlalchemy import select
from sqlalchemy.orm import Session

from mixcount.catalog.decisions import latest_pair_decisions
from mixcount.catalog.models import CatalogObject, Flag
from mixcount.curation.flag_kinds import DECIDE, DECIDED_MARK, severity
from mixcount.curation.renders import canonical_render_path

PAIR_BUTTONS = (("same", "same object"), ("variants", "variants, keep both"), ("different", "different"))


@dataclass
class PairSide:
    id: int
    name: str
    category: str
    status: str
    dims_m: tuple[float, float, float]
    source: str
    render: Path | None


@dataclass
class PairView:
    a: PairSide
    b: PairSide
    severity: str
    score: float
    evidence: list[tuple[str, float, str]] = field(default_factory=list)  # (kind, score, reason)
    decided: str | None = None  # the latest pair decision, if any

    @property
    def key(self) -> str:
        return f"{self.a.id}-{self.b.id}"


def _side(session: Session, obj: CatalogObject) -> PairSide:
    source = f"{obj.source}: {obj.source_id}" if obj.source_id else str(obj.source or "")
    return PairSide(obj.id, obj.name, obj.category, obj.status, obj.dims, source, canonical_render_path(session, obj.id))


def pair_views(session: Session, ids: set[int] | None = None) -> list[PairView]:
    """Every flagged pair with an end among ``ids`` (all when None): decide first, then info, each by score."""
    flags = session.scalars(select(Flag).where(Flag.pair_object_id.is_not(None)).order_by(Flag.id)).all()
    decided = latest_pair_decisions(session)
    views: dict[frozenset[int], PairView] = {}
    for f in flags:
        a_id, b_id = sorted((f.object_id, int(f.pair_object_id)))  # type: ignore[arg-type]
        if ids is not None and a_id not in ids and b_id not in ids:
            continue
        key = frozenset((a_id, b_id))
        view = views.get(key)
        if view is None:
            a, b = session.get(CatalogObject, a_id), session.get(CatalogObject, b_id)
            if a is None or b is None:
                continue
            rd = decided.get(key)
            view = views[key] = PairView(_side(session, a), _side(session, b), "info", 0.0,
                                         decided=rd.decision if rd is not None else None)
        if f.object_id != a_id and any(k == f.kind for k, _, _ in view.evidence):
            continue  # the same flag seen from the other end
        reason = (f.reason or "").split(DECIDED_MARK)[0].strip()
        view.evidence.append((f.kind, float(f.score), reason))
        view.score = max(view.score, float(f.score))
        if severity(f.kind, f.reason or "") == DECIDE:
            view.severity = DECIDE
    return sorted(views.values(), key=lambda v: (v.severity != DECIDE, -v.score, v.a.id, v.b.id))


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _size(dims: tuple[float, float, float]) -> str:
    return " x ".join(f"{100 * d:.1f}" for d in dims) + " cm"


def _card(v: PairView, thumb: Callable[[int, Path | None], str]) -> str:
    sides = "".join(
        f"<figure class=\"side\"><img class=\"pthumb\" alt=\"#{s.id}\" src=\"{thumb(s.id, s.render)}\">"
        f"<figcaption><a href=\"#obj-{s.id}\">#{s.id}</a> <span class=\"name\">{_e(s.name)}</span><br>"
        f"<span class=\"meta\">{_e(s.category)} · {_e(s.status)} · {_e(_size(s.dims_m))}<br>{_e(s.source)}</span>"
        "</figcaption></figure>" for s in (v.a, v.b))
    evidence = "".join(f"<li data-kind=\"{_e(k)}\"><span class=\"kind\">{_e(k)}</span> <span class=\"score\">{sc:.2f}</span> "
                       f"<span class=\"reason\">{_e(r)}</span></li>" for k, sc, r in v.evidence)
    decided = f"<p class=\"decided\">decided: {_e(v.decided)}</p>" if v.decided else ""
    buttons = "".join(f"<button type=\"button\" class=\"pair-decision {d}\" data-decision=\"{d}\">{label}</button>"
                      for d, label in PAIR_BUTTONS)
    return (f"<article class=\"paircard sev-{_e(v.severity)}\" id=\"pair-{v.key}\" data-pair=\"{v.key}\">"
            f"<div class=\"sides\">{sides}</div><ul class=\"evidence\">{evidence}</ul>{decided}"
            f"<div class=\"pair-review\">{buttons}<input class=\"pair-note\" type=\"text\" placeholder=\"note\"></div>"
            "</article>")


def pairs_html(views: list[PairView], thumb: Callable[[int, Path | None], str]) -> str:
    """The two pair sections of the page."""
    decide = [v for v in views if v.severity == DECIDE]
    info = [v for v in views if v.severity != DECIDE]
    return (f"<section id=\"pairs-decide\"><h2>pairs to decide ({len(decide)})</h2><div class=\"pairgrid\">"
            + "".join(_card(v, thumb) for v in decide)
            + f"</div></section><section id=\"pairs-info\"><h2>look-alikes and decided pairs, for information "
            f"({len(info)})</h2><div class=\"pairgrid\">" + "".join(_card(v, thumb) for v in info) + "</div></section>")


def pairs_data(views: list[PairView]) -> dict[str, dict[str, Any]]:
    """What the page's script needs to export a pair decision."""
    return {v.key: {"a": v.a.id, "b": v.b.id, "a_name": v.a.name, "b_name": v.b.name} for v in views}
