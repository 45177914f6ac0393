"""Fuzzing ``--set`` overrides and ``metadata.json`` side files (issue 60): an override either loads or
is one ConfigError; a metadata.json beside a model either gives the object its identity or marks it broken
with a one-line reason; discovery itself never raises."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fuzz_settings import NUMBER_TEXT, deep, dumps_loose, fuzz, json_values
from hypothesis import example, given
from hypothesis import strategies as st

from mixcount.catalog.layouts.discovery import discover
from mixcount.config import load_config
from mixcount.errors import ConfigError


def _keys(node: dict, prefix: str = "") -> list[str]:
    out: list[str] = []
    for k, v in node.items():
        out += _keys(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
    return out


KEYS = _keys(load_config().to_dict())
VALUE = st.one_of(NUMBER_TEXT, st.text(max_size=20), st.sampled_from(["[1, 2]", "[[1]]", deep(3000), "true", '"x"',
                                                                    "{a = 1}", "[30, 1e999]", "inf", "nan"]))


FLOAT_KEY = next(k for k in KEYS if isinstance(load_config().to_dict()[k.split(".")[0]].get(k.split(".", 1)[1]), float))


@fuzz(300)
@example(FLOAT_KEY, "1" + "0" * 400, "=")  # found at 3,000 cases: an OverflowError in the float coercion
@example("scene.n_objects", deep(3000), "=")  # found at 300 cases: a RecursionError in tomllib
@example("scene.floor_patterns", "[[1]]", "=")  # found in CI: a TypeError (unhashable list) in the scene validator
@given(st.one_of(st.sampled_from(KEYS), st.text(max_size=15)), VALUE, st.sampled_from(["=", "", "=="]))
def test_set_overrides(key: str, value: str, sep: str) -> None:
    try:
        load_config([], [f"{key}{sep}{value}"])
    except ConfigError as exc:
        assert str(exc)


def _value_at(dotted: str) -> object:
    node: object = load_config().to_dict()
    for part in dotted.split("."):
        node = node[part]  # type: ignore[index]
    return node


LIST_KEYS = [k for k in KEYS if isinstance(_value_at(k), list)]
ITEMS_OF_EVERY_KIND = ["[[1]]", "[1]", '["x"]', "[true]", "[{a = 1}]", "[1.5, \"a\"]", "[[]]"]


@pytest.mark.parametrize("key", LIST_KEYS)
def test_list_items_of_another_kind_are_one_config_error(key: str) -> None:
    """Every list key, every kind of item: it loads or stops as one ConfigError that names the key (the
    class of the CI failure above, not only floor_patterns)."""
    assert len(LIST_KEYS) >= 30
    refused = 0
    for value in ITEMS_OF_EVERY_KIND:
        try:
            load_config([], [f"{key}={value}"])
        except ConfigError as exc:
            refused += 1
            assert key.split(".")[-1] in str(exc), str(exc)
    assert refused >= 4  # at most three kinds (an array of arrays is never one) can fit a key


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fuzz_meta")
    (root / "mug").mkdir()
    (root / "mug" / "mug.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    return root


META_KEYS = st.sampled_from(["name", "category", "license", "units", "up_axis", "metadata", "title", "value"])


@fuzz(250)
@given(st.one_of(json_values(META_KEYS).map(dumps_loose), st.text(max_size=30),
                 st.sampled_from([deep(100_000), deep(500, "{"), '{"name": 1' + "0" * 5000 + "}", '{"name": NaN}'])))
def test_metadata_json_beside_a_model(library: Path, text: str) -> None:
    (library / "mug" / "metadata.json").write_text(text, encoding="utf-8", errors="surrogatepass")
    found = discover([library])
    assert len(found) == 1
    cand = found[0]
    assert cand.error is None or ("\n" not in cand.error and len(cand.error) < 600), cand.error
    json.dumps(cand.metadata, default=str)  # what ingest stores
