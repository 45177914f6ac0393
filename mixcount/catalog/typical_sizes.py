"""The typical size of an object's kind: the table ``mixcount/data/typical_sizes.csv`` (issue 70).

A model whose size carries no meaning (normalised into a unit cube by an image-to-3D tool, or implausible
for its kind) takes its kind's typical largest side (:func:`mixcount.sizes.decide_size`). Each row is a
kind, its other names, its typical largest side and a plausible range in metres, and the reference the
figure comes from (a datasheet, a package or sports standard, a product-dimension listing).
:func:`kind_size` finds an object's kind from the words of its category and of its name (the longest
name of a kind found first, a plural "s"/"es" allowed).
"""

from __future__ import annotations

import csv
import io
from dataclasses import replace
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Optional, Sequence

import numpy as np

from mixcount.errors import IngestError
from mixcount.frame import unit_scale
from mixcount.scene.words import words_of
from mixcount.sizes import SIZE_NONE, KindSize, SizeDecision, decide_size, looks_normalised, parse_size

TABLE = "typical_sizes.csv"


@lru_cache(maxsize=1)
def table() -> tuple[tuple[tuple[str, ...], KindSize], ...]:
    """(words of one name of the kind, its row) for every name of every kind, longest names first."""
    text = resources.files("mixcount.data").joinpath(TABLE).read_text("utf-8")
    out: list[tuple[tuple[str, ...], KindSize]] = []
    for row in csv.DictReader(io.StringIO(text)):
        size = KindSize(row["kind"], float(row["typical_m"]), float(row["min_m"]), float(row["max_m"]),
                        row["source"])
        for name in [row["kind"], *filter(None, (row["aliases"] or "").split("|"))]:
            out.append((tuple(words_of(name)), size))
    out.sort(key=lambda e: -len(e[0]))
    return tuple(out)


def _forms(words: list[str]) -> list[set[str]]:
    return [{w, w[:-1] if w.endswith("s") else w, w[:-2] if w.endswith("es") else w} for w in words]


def _holds(forms: list[set[str]], name: tuple[str, ...]) -> bool:
    n = len(name)
    return any(all(name[j] in forms[i + j] for j in range(n)) for i in range(len(forms) - n + 1))


def kind_size(name: str, category: str) -> Optional[KindSize]:
    """The typical size of the object's kind: the longest name of a kind found in the words of its category
    or of its name ("Soccer ball" of category "ball" is a soccer ball), the category first at equal length;
    None when neither names one."""
    cat, own = _forms(words_of(category or "")), _forms(words_of(name or ""))
    for words, size in table():
        if _holds(cat, words) or _holds(own, words):
            return size
    return None


def size_decision(largest_m: float, extents_file: Any, centre_file: Any, units_reason: str,
                  hint: Optional[dict[str, Any]]) -> SizeDecision:
    """:func:`mixcount.sizes.decide_size` for one model: ``largest_m`` its largest side as read in its unit,
    ``extents_file`` / ``centre_file`` its box in the file's own numbers (for :func:`looks_normalised`),
    ``units_reason`` why it is read in that unit (a unit the user stated or a description file's scale, a
    URDF / MJCF / SDF, is the model's word on its size: never second-guessed), ``hint`` the ingest's ``size_hint`` (name, category, the
    stated size and who stated it)."""
    hint = hint or {}
    stated = parse_size(hint.get("stated")) if hint.get("stated") is not None else None
    return decide_size(largest_m, normalised=looks_normalised(extents_file, centre_file),
                       unit_stated=(units_reason or "").startswith(("stated", "description")), stated_m=stated,
                       stated_by=str(hint.get("stated_by") or "stated"),
                       kind=kind_size(str(hint.get("name") or ""), str(hint.get("category") or "")))


def sized(norm: Any, units_reason: str, hint: Optional[dict[str, Any]]) -> tuple[Any, str, Optional[str]]:
    """A loaded model (:class:`mixcount.catalog.mesh.NormalisedMesh`, metres Z-up) at its real size:
    (the model, scaled when its size came from a stated or typical size; the unit reason, which then says
    so and the unit is metres per unit as a number; the size source). Without a hint (a caller that does
    not size): the model as it is and no source."""
    if hint is None:
        return norm, units_reason, None
    try:
        mpu = unit_scale(norm.source_units)
    except ValueError:
        return norm, units_reason, SIZE_NONE
    full = norm.full
    extents = np.asarray(full.extents if full is not None else norm.mesh.extents, dtype=np.float64)
    centre = np.asarray(norm.mesh.bounds, dtype=np.float64).mean(axis=0)
    decision = size_decision(float(extents.max()), extents / mpu, centre / mpu, units_reason, hint)
    if decision.source == SIZE_NONE:
        return norm, "; ".join(filter(None, [units_reason, decision.detail])), decision.source
    if abs(decision.factor - 1.0) < 1e-9:
        return norm, units_reason, decision.source
    f = decision.factor
    norm.mesh.apply_scale(f)
    if full is not None:
        full = replace(full, extents=tuple(float(e) * f for e in full.extents), area=full.area * f ** 2,
                       volume=None if full.volume is None else full.volume * f ** 3)
    reason = f"{decision.detail} (unit was: {norm.source_units}, {units_reason or 'assumed'})"
    return replace(norm, source_units=f"{mpu * f:.6g}", full=full), reason, decision.source


def check_size_of(values: Sequence[str]) -> list[tuple[Path, float, str]]:
    """``catalog ingest --size-of DIR=SIZE`` values checked: (folder, largest side in metres, the value as
    given); an IngestError names a value without ``=`` or whose size does not read (:func:`parse_size`)."""
    out = []
    for value in values:
        folder, sep, size = value.rpartition("=")
        metres = parse_size(size) if sep and folder else None
        if metres is None:
            raise IngestError(f"--size-of {value!r}: give FOLDER=SIZE, the size of every object under FOLDER as "
                              "its largest side (\"14 mm\", \"3.5 in\", \"0.2\" in metres, or \"120x80x15mm\")")
        out.append((Path(folder).expanduser().resolve(), metres, value))
    return out


def apply_size_of(candidates: Iterable[Any], values: Sequence[str]) -> None:
    """A size stated for whole folders (``--size-of``): every candidate under a folder whose metadata.json
    states no ``size`` takes it (the deepest folder given wins), said as ``catalog ingest --size-of ...``."""
    rules = sorted(check_size_of(values), key=lambda r: -len(r[0].parts))
    if not rules:
        return
    for cand in candidates:
        if cand.model_path is None or cand.metadata.get("size") is not None:
            continue
        where = Path(cand.metadata.get("source_model_path") or cand.model_path).resolve()
        for folder, metres, value in rules:
            if folder == where or folder in where.parents:
                cand.metadata["size"] = f"{metres:.6g}"
                cand.metadata["size_stated_by"] = f"catalog ingest --size-of {value}"
                break
