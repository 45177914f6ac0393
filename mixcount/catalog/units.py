"""Which unit a model is read in, and why (docs/ingest.md, "Units").

The first that speaks decides:

1. **stated**: a ``units`` entry in the object's ``metadata.json`` (a unit name, or metres per unit as a
   number or a string), then ``catalog ingest --units mm|cm|m|in|ft`` (``auto``: say nothing); beside any
   format, glTF included (exporters write centimetres into GLBs). USD (``metersPerUnit``) and STEP (its
   length unit) state their own, which wins;
2. **description**: the mesh ``scale`` of a URDF / SDF / MJCF beside the model (or a layout's
   convention: GSO is metres, OmniObject3D ``ingest.omniobject3d_units``);
3. **format**: glTF is metres by its specification, USD says, STEP states its length unit (OpenCASCADE
   reads it into metres: the unit recorded is "m", the unit the file states is kept in the reason and shown
   by :func:`shown_unit`, so that ``catalog list`` says "mm" for a STEP drawn in millimetres); STL from CAD
   and 3D-printing tools is millimetres;
4. **default**: ``ingest.assume_units`` for OBJ / PLY.

After 3 (STL) the **size prior** has its say in the analysis: a largest side that no everyday object has
in the assumed millimetres is re-read in the unit that makes it plausible
(:func:`mixcount.sizes.plausible_unit`; :func:`mixcount.catalog.mesh.analyse_model`); otherwise an
implausible size is only said (the reason names the unit that would fit, ingest prints a warning and
``--units`` re-reads). A stated unit is never second-guessed. The unit and its reason are recorded beside the up axis.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mixcount.errors import IngestError
from mixcount.frame import GLTF_EXTENSIONS, STEP_EXTENSIONS, UNIT_SCALE, unit_scale

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


@dataclass(frozen=True)
class UnitDecision:
    """``unit`` (a name or metres per unit as text) and ``reason`` (a sentence that starts with its basis:
    stated, description, format, default; :func:`size_prior` reads what the size prior may do from it)."""

    unit: str
    reason: str


def check_units(value: str | None) -> str | None:
    """``--units`` checked: a unit name (lower case) or metres per unit; None for ``auto`` or nothing."""
    if value is None or value.strip().lower() == "auto":
        return None
    text = value.strip().lower()
    try:
        unit_scale(text)
    except ValueError:
        raise IngestError(f"unknown units {value!r}: give {', '.join(UNIT_SCALE)}, auto, or metres per unit "
                          "as a number") from None
    return text


def decide_units(source: Path, *, units: str | None, units_reason: str | None, stated: str | None,
                 assume: str, layout: str) -> UnitDecision:
    """The unit of a model whose original file is ``source`` (the first part of a multi-part object, a
    STEP file before conversion): ``units``/``units_reason`` are what its metadata or description said,
    ``stated`` is ``--units``, ``assume`` is ``ingest.assume_units``."""
    suffix = source.suffix.lower()
    carries = suffix in USD_SUFFIXES or suffix in STEP_EXTENSIONS  # the file states its unit
    from_metadata = bool(units) and (units_reason or "").startswith("stated")
    if from_metadata and not carries:
        return UnitDecision(str(units), f"stated: units {units} in the object's metadata.json")
    if stated and not carries:
        return UnitDecision(stated, f"stated: catalog ingest --units {stated}")
    if units:
        return UnitDecision(str(units), units_reason or f"description: the {layout} layout's convention")
    if suffix in USD_SUFFIXES:
        return UnitDecision("m", "format: USD states metersPerUnit")
    if suffix in GLTF_EXTENSIONS:
        return UnitDecision("m", "format: glTF is metres by its specification")
    if suffix in STEP_EXTENSIONS:
        own = step_length_unit(source)
        return UnitDecision("m", f"format: {STEP_STATES}{own} (read into metres by OpenCASCADE)" if own else
                            "format: STEP states its length unit (read into metres by OpenCASCADE)")
    if suffix == ".stl":
        return UnitDecision("mm", "format: STL from CAD and 3D-printing tools is millimetres")
    return UnitDecision(assume, f"default: ingest.assume_units ({assume}) for {suffix.lstrip('.').upper()}")


STEP_STATES = "the STEP file states "  # the reason's words before the file's own unit (shown_unit reads it)
# the length unit of a STEP (ISO 10303-21): a complex entity holding LENGTH_UNIT(), an SI unit with its prefix
# or a unit converted from one ('INCH', 'FOOT'); case as the standard writes it, any spacing
_LENGTH_UNIT = re.compile(r"\(\s*[^;]*?LENGTH_UNIT\s*\(\s*\)[^;]*;", re.IGNORECASE)
_SI_UNIT = re.compile(r"SI_UNIT\s*\(\s*(\$|\.(\w+)\.)\s*,\s*\.METRE\.\s*\)", re.IGNORECASE)
_CONVERTED = re.compile(r"CONVERSION_BASED_UNIT\s*\(\s*'([^']*)'", re.IGNORECASE)
_SI_PREFIX = {"": "m", "milli": "mm", "centi": "cm", "deci": "dm", "kilo": "km", "micro": "um"}
_NAMED = {"inch": "in", "in": "in", "foot": "ft", "ft": "ft", "millimetre": "mm", "millimeter": "mm", "mm": "mm",
          "metre": "m", "meter": "m", "centimetre": "cm", "centimeter": "cm"}


def step_length_unit(path: Path, *, limit: int = 4 << 20) -> str | None:
    """The length unit a STEP file states ("mm", "m", "in", ...; the first length unit of its data section),
    or None when none is found in its first ``limit`` bytes or the file cannot be read. OpenCASCADE reads the
    geometry into metres whatever it is; this is only what the file said, for the user to see."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(limit).decode("latin-1")
    except OSError:
        return None
    for entity in _LENGTH_UNIT.finditer(text):
        body = entity.group(0)
        named = _CONVERTED.search(body)
        if named:
            return _NAMED.get(named.group(1).strip().lower(), named.group(1).strip().lower() or None)
        si = _SI_UNIT.search(body)
        if si:
            return _SI_PREFIX.get((si.group(2) or "").lower())
    return None


def shown_unit(units: str | None, reason: str | None) -> str:
    """The unit to show for an object: the file's own where the model was read into another (a STEP in
    millimetres read into metres shows "mm"), else the unit it was read in."""
    text = reason or ""
    if STEP_STATES in text:
        return text.split(STEP_STATES, 1)[1].split(" ", 1)[0]
    return units or ""


def units_reason_of(metadata_json: str | None) -> str | None:
    """The unit's reason recorded with an object (``metadata_json["ingest"]["units_reason"]``), or None."""
    import json

    try:
        data = json.loads(metadata_json or "{}")
    except ValueError:
        return None
    ingest = data.get("ingest") if isinstance(data, dict) else None
    reason = ingest.get("units_reason") if isinstance(ingest, dict) else None
    return reason if isinstance(reason, str) else None


def decide_frame(cand: Any, *, stated: str | None, assume: str) -> None:
    """Set a candidate's ``units`` and ``units_reason`` by :func:`decide_units`, judged on its original
    file (a multi-part object's first part, a staged or derived model's source)."""
    if cand.model_path is None or cand.error:
        return
    source = cand.parts[0][0] if cand.parts else Path(cand.metadata.get("source_model_path") or cand.model_path)
    decision = decide_units(source, units=cand.units, units_reason=cand.units_reason, stated=stated,
                            assume=assume, layout=cand.layout)
    cand.units, cand.units_reason = decision.unit, decision.reason


def basis(reason: str | None) -> str:
    """The first word group of a reason: stated, description, format, default or size prior."""
    return (reason or "").split(":", 1)[0] or "unknown"


def size_prior(reason: str | None) -> str | None:
    """What the size prior may do to a unit decided for this ``reason`` (the one place that decides it):

    * ``"reread"``: an STL's assumed millimetres; a largest side no everyday object has is re-read in the
      unit that makes it plausible;
    * ``"say"``: any other unit not stated (an OBJ/PLY read by ``ingest.assume_units``, a description's, a
      format's); an implausible size is said, the reason naming the unit that would fit, not re-read: the
      configured assumption is the user's word for the library;
    * None: a stated unit (never second-guessed), or no reason."""
    if not reason or reason.startswith("stated"):
        return None
    return "reread" if reason.startswith("format: STL") else "say"


def note_units(rescaled: list[tuple[str, str, str]], implausible: list[tuple[str, str]], name: str,
               unit: str | None, reason: str | None) -> None:
    """Note an ingested object in an ingest summary's lists: ``rescaled`` when it is read in a unit other
    than metres, ``implausible`` when its size was said to be implausible (not re-read)."""
    if unit and unit != "m":
        rescaled.append((name, unit, reason or ""))
    if "would be" in (reason or "") or "no trustworthy size" in (reason or ""):
        implausible.append((name, reason or ""))


def units_summary(rescaled: list[tuple[str, str, str]], implausible: list[tuple[str, str]]) -> dict[str, Any]:
    """The units part of an ingest summary's JSON: who was read in which unit and why, counts per basis."""
    return {"rescaled": [{"name": n, "units": u, "reason": r} for n, u, r in rescaled],
            "rescaled_by": dict(sorted(Counter(basis(r) for _n, _u, r in rescaled).items())),
            "implausible_sizes": [{"name": n, "reason": r} for n, r in implausible]}
