"""Copies of real captures as other sources make them (issue 57; tests/capture_copies.py), each kind of copy on
its own, and look-alikes of one kind that must stay apart. A lean slice runs here: pybullet's textured duck
and glmark2-data's untextured Stanford bunny, each with its seven copies (another print, another resolution,
a squash, other units, another pose, re-indexed, and a compound of units, squash, pose and resolution or print:
issue 69), and metaworld's cup, pybullet's mug and genesis-world's
bolt and nut beside them. The whole pool
(13 originals of five packages, the held-back part apart) is ``python bench/curation_copies.py``.

* every copy is a candidate (the index) and paired for a decision (a duplicate, variant or possible copy);
* no pair of different objects to decide, no duplicate between different objects."""

from __future__ import annotations

import pytest
from capture_copies import KINDS, evaluate, pool

from mixcount.config import load_config

pytestmark = pytest.mark.slow


def test_copies_of_real_captures_each_kind():
    entries, why = pool(("tuning",), only={"duck_pybullet", "bunny_glmark2", "cup_metaworld", "mug_pybullet", "bolt_genesis", "nut_genesis"},
                        demo_look_alikes=False)
    if entries is None:
        pytest.skip(why)
    got = evaluate(entries, load_config().filter)
    per = got["per_kind"]["tuning"]
    print(f"\nreal-capture copies (slice): {got['objects']} objects, per kind "
          f"{ {k: (v['candidates'], v['paired'], v['copies']) for k, v in per.items()} } (candidates, paired, copies); "
          f"decide pairs {got['decide_pairs']}, precision {got['precision']}, false {got['false_pairs']}")
    assert set(per) == set(KINDS)
    assert all(v["candidates"] == v["copies"] == 2 for v in per.values()), per
    assert all(v["paired"] == v["copies"] for v in per.values()), got["missed"]
    assert got["false_pairs"] == [] and got["false_duplicates"] == []
