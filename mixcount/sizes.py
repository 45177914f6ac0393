"""Real sizes and units: the one place that says what a plausible object size is and which size ratios a
unit error explains.

Two sides of the product need the same facts and must not drift apart:

* **ingest** decides a model's unit (what the user says, a description file's scale, the format's
  convention, then a size prior): :func:`plausible_unit` re-reads a largest side that is implausible in
  the assumed unit in the unit that makes it plausible;
* **curation** weighs a size ratio between two objects: a ratio that a unit mix-up or a modest rescale
  explains (1000 x for mm read as m, 25.4 x for inches read as mm, ...) is no evidence against a copy,
  any other large ratio is (:func:`unit_explained_ratio`, :func:`size_ratio_evidence`).

Unit names and metres-per-unit come from :data:`mixcount.frame.UNIT_SCALE` (the frame normalisation's
table); pure Python, no numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Optional

from mixcount.frame import UNIT_SCALE

# Everyday countable objects (a washer, a grain of rice at the small end; a chair, a suitcase at the large
# end): the largest side in metres that a size prior accepts without comment. The filter's size_outlier
# bounds ([filter] min_size_m / max_size_m) are narrower on purpose: they flag, this only re-reads units.
PLAUSIBLE_MIN_M = 0.002
PLAUSIBLE_MAX_M = 2.5

# Unit names in the order a re-read prefers them when several make a size plausible (CAD's millimetres
# first, then the rest by how often exporters use them).
UNIT_PREFERENCE = ("mm", "m", "cm", "in", "ft")


def metres_per_unit(unit: str) -> float:
    """Metres per unit for a unit name (``mm``, ``cm``, ``m``, ``in``, ``ft``); KeyError otherwise."""
    return UNIT_SCALE[unit.lower()]


def is_plausible(largest_side_m: float) -> bool:
    """True when a largest side (metres) is one an everyday object has."""
    return PLAUSIBLE_MIN_M <= largest_side_m <= PLAUSIBLE_MAX_M


@dataclass(frozen=True)
class UnitChoice:
    """The unit a model is read in and why: ``reason`` is one of ``stated`` (the user or a metadata entry),
    ``description`` (a URDF / MJCF / SDF mesh scale), ``format`` (the format's convention: glTF and USD say,
    STL / STEP from CAD tools are millimetres), ``default`` (the configured assumption), ``size prior``
    (re-read because the assumed unit gave an implausible size). ``detail`` is a sentence for people."""

    unit: str
    reason: str
    detail: str = ""


def plausible_unit(largest_side_in_units: float, assumed: str, *,
                   candidates: Iterable[str] = UNIT_PREFERENCE) -> Optional[str]:
    """The unit to re-read a model in when its largest side, ``largest_side_in_units`` in the file's own
    numbers, is implausible in ``assumed``; None when the assumed unit is plausible (or no unit is).

    The first unit of ``candidates`` (CAD's millimetres first, :data:`UNIT_PREFERENCE`) that makes the size
    plausible wins: the size alone cannot tell a 6 mm nut from a 6 cm one, and millimetres are what
    unit-less exports most often are."""
    if not (largest_side_in_units > 0 and math.isfinite(largest_side_in_units)):
        return None
    if is_plausible(largest_side_in_units * metres_per_unit(assumed)):
        return None
    for unit in candidates:
        if is_plausible(largest_side_in_units * metres_per_unit(unit)):
            return unit
    return None


# Ratios between two unit names (larger / smaller metres-per-unit): 1000 (mm/m), 100, 10, 25.4 (in/mm),
# 2.54 (in/cm), 39.37 (m/in), 12 (ft/in), 3.28 (m/ft), 304.8 (ft/mm), 30.48 (ft/cm).
UNIT_RATIOS: dict[str, float] = {}
for _a, _sa in UNIT_SCALE.items():
    for _b, _sb in UNIT_SCALE.items():
        if _sa > _sb:
            UNIT_RATIOS[f"{_a}/{_b}"] = _sa / _sb


def unit_explained_ratio(ratio: float, *, tolerance: float = 0.06) -> Optional[str]:
    """The unit pair (``"m/mm"``, ``"in/mm"``, ...) whose conversion factor a size ratio (>= 1 or <= 1, the
    order does not matter) matches within ``tolerance`` (relative, in log scale), or None."""
    if not (ratio > 0 and math.isfinite(ratio)):
        return None
    r = ratio if ratio >= 1 else 1.0 / ratio
    for name, factor in sorted(UNIT_RATIOS.items(), key=lambda kv: kv[1]):
        if abs(math.log(r / factor)) <= math.log1p(tolerance):
            return name
    return None


@dataclass(frozen=True)
class SizeEvidence:
    """What a size ratio between two objects says about them being one object.

    ``against`` is True when the ratio is beyond what a rescale (``rescale_limit``) or a unit error
    explains; ``explained_by`` names the unit pair or ``"rescale"`` when it is explained."""

    ratio: float
    against: bool
    explained_by: Optional[str]

    def describe(self) -> str:
        if self.explained_by == "rescale" or self.ratio < 1.0 + 1e-9:
            return f"real sizes agree within {self.ratio:.2f}x"
        if self.explained_by:
            return f"real sizes differ {self.ratio:.2f}x, as a unit error ({self.explained_by}) would make them"
        return f"real sizes differ {self.ratio:.2f}x, more than a rescale or a unit error explains"


def size_ratio_evidence(size_a_m: float, size_b_m: float, *, rescale_limit: float = 1.35,
                        tolerance: float = 0.06) -> SizeEvidence:
    """Weigh two largest sides (metres): within ``rescale_limit`` x (a squash of up to 25 % and a small
    rescale) or at a unit factor is no evidence against a copy; anything else is."""
    lo, hi = sorted((abs(size_a_m), abs(size_b_m)))
    if not (lo > 0 and math.isfinite(hi)):
        return SizeEvidence(float("inf"), True, None)
    ratio = hi / lo
    if ratio <= rescale_limit:
        return SizeEvidence(ratio, False, "rescale")
    unit = unit_explained_ratio(ratio, tolerance=tolerance)
    return SizeEvidence(ratio, unit is None, unit)


# ------------------------------------------------------------------------------------ a size per object
# Where an object's real size comes from (issue 70), recorded per object (``objects.size_source``):
SIZE_STATED = "stated"  # the user: a ``size`` entry in metadata.json or ``catalog ingest --size-of``
SIZE_MODEL = "model"  # the model in its unit (the file's, a description's, a stated or assumed one)
SIZE_KIND = "kind"  # the typical size of the object's kind (mixcount/data/typical_sizes.csv)
SIZE_NONE = "none"  # no trustworthy size: normalised or implausible, and no kind in the table
SIZE_SOURCES = (SIZE_STATED, SIZE_MODEL, SIZE_KIND, SIZE_NONE)
TRUSTED_SIZE_SOURCES = (SIZE_STATED, SIZE_MODEL, SIZE_KIND)

# A model normalised as image-to-3D tools write them (TRELLIS, InstantMesh, Hunyuan3D, ...): its largest
# side is 1 or 2 in the file's numbers (the [-0.5, 0.5] or [-1, 1] cube) within this share ...
NORMALISED_SIDES = (1.0, 2.0)
NORMALISED_TOLERANCE = 0.02
# ... and its box is centred on the origin within this share of the largest side on every axis
NORMALISED_CENTRE = 0.05
# A model's size is implausible for its kind beyond this factor outside the kind's [min, max] range.
KIND_SLACK = 3.0


def parse_size(value: object) -> Optional[float]:
    """A stated size as the largest side in metres: a number (metres), a string with a unit ("14 mm",
    "3.5in", "0.2 m", "12" = metres) or a list of three such values ([x, y, z]: the largest is taken).
    None for anything else or a size that is not positive."""
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (list, tuple)):
        sides = [parse_size(v) for v in value]
        return max(sides) if len(sides) == 3 and all(s is not None for s in sides) else None  # type: ignore[type-var]
    if isinstance(value, (int, float)):
        return float(value) if value > 0 and math.isfinite(value) else None
    if not isinstance(value, str):
        return None
    text = value.strip().lower().replace(" ", "")
    if "x" in text and not text.endswith("x"):  # "120x80x15mm": the unit of the last applies to all
        parts = text.split("x")
        unit = parts[-1].lstrip("0123456789.")
        return parse_size([p if p.lstrip("0123456789.") else p + unit for p in parts]) if len(parts) == 3 else None
    number = text.rstrip("abcdefghijklmnopqrstuvwxyz\"'")
    unit = text[len(number):] or "m"
    unit = {'"': "in", "inch": "in", "inches": "in", "mm.": "mm"}.get(unit, unit)
    try:
        n = float(number)
        factor = metres_per_unit(unit)
    except (ValueError, KeyError):
        return None
    return n * factor if n > 0 and math.isfinite(n) else None


def looks_normalised(extents: Iterable[float], centre: Iterable[float]) -> bool:
    """True when a model's box (``extents`` and ``centre`` in the file's own numbers) is what an
    image-to-3D tool writes: its largest side 1 or 2 (:data:`NORMALISED_SIDES`) and its centre on the
    origin (a unit cube, whatever the object's real size)."""
    ext = [float(e) for e in extents]
    largest = max(ext)
    if not any(abs(largest - side) <= NORMALISED_TOLERANCE * side for side in NORMALISED_SIDES):
        return False
    return all(abs(float(c)) <= NORMALISED_CENTRE * largest for c in centre)


@dataclass(frozen=True)
class KindSize:
    """A kind's typical largest side and plausible range (metres) and the reference it comes from."""

    kind: str
    typical_m: float
    min_m: float
    max_m: float
    source: str

    def fits(self, largest_m: float, slack: float = KIND_SLACK) -> bool:
        """True when a largest side is within ``slack`` x outside the kind's range."""
        return self.min_m / slack <= largest_m <= self.max_m * slack


@dataclass(frozen=True)
class SizeDecision:
    """An object's real size and where it comes from: ``factor`` multiplies the model as read in its unit
    (1.0: the model's size kept), ``source`` one of :data:`SIZE_SOURCES`, ``detail`` a sentence."""

    factor: float
    source: str
    detail: str

    @property
    def trusted(self) -> bool:
        return self.source in TRUSTED_SIZE_SOURCES


def decide_size(largest_m: float, *, normalised: bool, unit_stated: bool, stated_m: Optional[float],
                stated_by: str = "", kind: Optional[KindSize] = None) -> SizeDecision:
    """The real size of a model whose largest side is ``largest_m`` as read in its unit. First that speaks:

    1. a size the user stated (``stated_m``, said by ``stated_by``): the model is scaled to it;
    2. a unit the user or a description file stated (``unit_stated``): the model's size, never second-guessed;
    3. the model's own size when it means something: not ``normalised`` and plausible for its ``kind``
       (within :data:`KIND_SLACK` x of its range), or, without a kind, for an everyday object;
    4. the kind's typical size for a normalised model of a kind in the table;
    5. none (untrusted: the real-size scene rule refuses it): a normalised model of a kind the table
       lacks, or a model whose size in its unit is implausible. Such a size is said (with the kind's
       typical size), not replaced: as the unit rule's size prior, only the user's word or an STL's assumed
       millimetres are re-read, and a copy stored in the wrong unit stays what curation finds
       (the demo library's rescaled traps)."""
    if not (largest_m > 0 and math.isfinite(largest_m)):
        return SizeDecision(1.0, SIZE_NONE, "no size: the model has no extent")
    if stated_m is not None:
        return SizeDecision(stated_m / largest_m, SIZE_STATED,
                            f"stated size: {_length(stated_m)} ({stated_by}); the model was {_length(largest_m)}")
    if unit_stated:
        return SizeDecision(1.0, SIZE_MODEL, f"model: {_length(largest_m)} in the stated unit")
    give = "give \"size\" in metadata.json, e.g. \"size\": \"14 mm\", or catalog ingest --size-of FOLDER=SIZE"
    if normalised:
        why = f"normalised into a unit cube (largest side {largest_m:.3g} in the file, centred)"
        if kind is None:
            return SizeDecision(1.0, SIZE_NONE, f"no trustworthy size: {why}, and no typical size for its kind ({give})")
        return SizeDecision(kind.typical_m / largest_m, SIZE_KIND,
                            f"typical size: {why}; a {kind.kind} is {_length(kind.typical_m)} ({kind.source})")
    if kind is not None and not kind.fits(largest_m):
        return SizeDecision(1.0, SIZE_NONE, f"no trustworthy size: {_length(largest_m)} is implausible for a "
                                            f"{kind.kind} ({_length(kind.min_m)}-{_length(kind.max_m)}; typically "
                                            f"{_length(kind.typical_m)}: {give})")
    if kind is None and not is_plausible(largest_m):
        return SizeDecision(1.0, SIZE_NONE, f"no trustworthy size: {_length(largest_m)} is no everyday object's "
                                            f"size ({give})")
    return SizeDecision(1.0, SIZE_MODEL, f"model: {_length(largest_m)} in its unit")


def _length(m: float) -> str:
    """A length for people: mm below 1 cm, cm below 1 m, else m."""
    if m < 0.01:
        return f"{m * 1000:.3g} mm"
    if m < 1.0:
        return f"{m * 100:.3g} cm"
    return f"{m:.3g} m"
