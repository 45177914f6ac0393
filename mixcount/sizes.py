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
