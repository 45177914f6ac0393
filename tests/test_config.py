from pathlib import Path

import pytest

from mixcount.config import load_config
from mixcount.errors import ConfigError


def test_defaults_load_and_hash_is_stable():
    a = load_config()
    b = load_config()
    assert a.hash == b.hash
    assert a["ingest"]["collision_face_budget"] == 2000


def test_quick_overlays_default():
    quick = load_config(["quick"])
    assert quick["render"]["resolution"] < load_config()["render"]["resolution"]
    assert quick.hash != load_config().hash


def test_unknown_key_is_an_error(tmp_path: Path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[ingest]\nno_such_key = 1\n")
    with pytest.raises(ConfigError, match="no_such_key"):
        load_config([bad])
    with pytest.raises(ConfigError, match="unknown config key"):
        load_config(overrides=["ingest.nope=3"])


def test_override_type_is_checked():
    cfg = load_config(overrides=["ingest.collision_face_budget=500", "ingest.assume_units=cm"])
    assert cfg["ingest"]["collision_face_budget"] == 500
    assert cfg["ingest"]["assume_units"] == "cm"
    with pytest.raises(ConfigError, match="expects int"):
        load_config(overrides=["ingest.collision_face_budget=abc"])


def test_config_is_read_only():
    cfg = load_config()
    with pytest.raises(TypeError):
        cfg["ingest"]["workers"] = 9  # type: ignore[index]
