"""Shared hypothesis settings of the fuzz tests (tests/test_fuzz_*.py, issue 60).

Derandomized (the same cases on every run and machine: the suite's randomness is seeded), no example
database written into the checkout, no per-example deadline (tests are not timed on 2 shared cores);
each test is bounded by its ``max_examples`` instead (to hunt longer, raise it by hand for one run).
"""

from __future__ import annotations

import json
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st


def fuzz(max_examples: int) -> settings:
    """The settings of one fuzz test: ``max_examples`` cases, derandomized, no deadline."""
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                           HealthCheck.data_too_large])


# Numbers users type and files hold: small, zero, negative, huge (past int64 and the float range as text),
# fractional, exponent forms.
NUMBER_TEXT = st.one_of(
    st.integers(-5, 300).map(str),
    st.integers(-(10**30), 10**30).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["0", "-0", "1e9", "1e400", "9" * 400, ".5", "5.", "1.2.3", "1_000", "0x10", "nan", "inf",
                     "-inf", "١٢", "", " ", "+3", "1e-400"]),
)

JSON_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**25), 10**25), st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=12), st.sampled_from([0, 1, -1, 3731, 10_000, 10_001, 1e308, -1e308, 2**63, "1", "[red]x[/red]"]),
)


def json_values(keys: st.SearchStrategy[str]) -> st.SearchStrategy[Any]:
    """JSON documents whose objects mostly use ``keys`` (the names a parser looks for)."""
    return st.recursive(JSON_SCALARS, lambda inner: st.one_of(
        st.lists(inner, max_size=6), st.dictionaries(st.one_of(keys, st.text(max_size=6)), inner, max_size=6)),
        max_leaves=40)


def deep(depth: int, kind: str = "[") -> str:
    """A JSON text nested ``depth`` levels (lists or objects)."""
    return "[" * depth + "]" * depth if kind == "[" else '{"a":' * depth + "1" + "}" * depth


def dumps_loose(doc: Any) -> str:
    """JSON text as Python writes it (NaN / Infinity allowed: what a careless exporter writes)."""
    return json.dumps(doc, allow_nan=True)
