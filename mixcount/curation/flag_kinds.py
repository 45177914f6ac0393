"""The flag kinds `catalog filter` writes, how they group, and the severity of each (docs/curation.md).

*decide* flags need a person (or are decisions the filter took that a person may overrule): copies,
variants to confirm, possible copies, collisions, unusable or out-of-size objects. *info* flags change no
decision: a usable mesh warning, a look-alike pair (different objects that look alike, the paper's
hard pairs, ranked for a person who wants them). ``catalog sheet --only flagged`` shows objects with a
*decide* flag; ``--only info`` the rest."""

from __future__ import annotations

EXACT = "exact_duplicate"
NEAR_GEOMETRY = "near_duplicate_geometry"
NEAR_APPEARANCE = "near_duplicate_appearance"
DEGENERATE = "degenerate"
SIZE_OUTLIER = "size_outlier"
MESH_QUALITY = "mesh_quality"
CAPTION_COLLISION = "caption_collision"  # written by captioning, never touched here
COLOUR_VARIANT = "colour_variant"  # same geometry, other appearance: both stay active (a class pair)
POSSIBLE_COPY = "possible_copy"  # maybe the same object from another source: for a person, never excluded
DUPLICATE_KINDS = (EXACT, NEAR_GEOMETRY, NEAR_APPEARANCE)
RELATION_KINDS = (COLOUR_VARIANT, POSSIBLE_COPY)  # pairings that exclude nothing
QUALITY_KINDS = (DEGENERATE, SIZE_OUTLIER, MESH_QUALITY)
LOOK_ALIKE = "look_alike"  # different objects whose shapes agree loosely: a hard pair, ranked, decides nothing
FILTER_KINDS = DUPLICATE_KINDS + RELATION_KINDS + (LOOK_ALIKE,) + QUALITY_KINDS
EXCLUDED_MARK = "[excluded by filter]"
APPEARANCE_RANK = {"image": 0, "vertex_color": 1, "material": 2, "none": 3}
PAIR_KINDS = DUPLICATE_KINDS + RELATION_KINDS + (LOOK_ALIKE,)
DECIDE = "decide"
INFO = "info"
INFO_KINDS = (MESH_QUALITY, LOOK_ALIKE)
DECIDED_MARK = "[decided by review:"  # a pair a person decided: the flag stays, as information


def decided_mark(decision: str, reviewer: str | None) -> str:
    """What a pair's flags carry once a person decided the pair (``same`` / ``variants`` / ``different``)."""
    return f"{DECIDED_MARK} {decision} by {reviewer or 'someone'}]"


def severity(kind: str, reason: str = "") -> str:
    """``decide`` or ``info`` for a flag of ``kind``; a pair a person already decided is ``info``."""
    if kind in INFO_KINDS or DECIDED_MARK in (reason or ""):
        return INFO
    return DECIDE
