import dataclasses
from pathlib import Path

import pytest

from mixcount.config import load_config
from mixcount.errors import ConfigError


def test_defaults_load_and_hash_is_stable():
    a = load_config()
    b = load_config()
    assert a.hash == b.hash
    assert a.ingest.collision_face_budget == 2000


def test_quick_overlays_default():
    quick = load_config(["quick"])
    assert quick.canonical_render.resolution < load_config().canonical_render.resolution
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
    assert cfg.ingest.collision_face_budget == 500
    assert cfg.ingest.assume_units == "cm"
    with pytest.raises(ConfigError, match="expects int"):
        load_config(overrides=["ingest.collision_face_budget=abc"])


def test_config_is_read_only():
    cfg = load_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.ingest.workers = 9  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.compose = cfg.compose  # type: ignore[misc]
    with pytest.raises(TypeError):
        cfg.data["ingest"]["workers"] = 9  # type: ignore[index]


def test_values_apply_after_files_and_overrides_and_are_recorded():
    cfg = load_config(["quick"], ["compose.samples=8"], values={"compose.samples": 2, "compose.split": "val"})
    assert (cfg.compose.samples, cfg.compose.split, cfg.compose.resolution) == (2, "val", 128)
    assert cfg.to_dict()["compose"]["samples"] == 2 and cfg.hash != load_config(["quick"]).hash
    with pytest.raises(ConfigError, match="expects int"):
        load_config(values={"compose.samples": "many"})
    with pytest.raises(ConfigError, match="unknown config key"):
        load_config(values={"compose.nope": 1})


def test_section_checks_run_at_load():
    with pytest.raises(ConfigError, match="split fractions"):
        load_config(overrides=["split.train_fraction=-1.0"])
    with pytest.raises(ConfigError, match="compose.split"):
        load_config(overrides=["compose.split=holdout"])
    with pytest.raises(ConfigError, match="captions.colour_source"):
        load_config(overrides=["captions.colour_source=guess"])
    with pytest.raises(ConfigError, match="low 3 > high 2"):
        load_config(overrides=["scene.n_classes=[3, 2]"])
    with pytest.raises(ConfigError, match="denoise_prefilter must be one of ACCURATE, FAST, NONE"):
        load_config(overrides=["compose.denoise_prefilter=BEST"])
    assert load_config(overrides=["compose.denoise_prefilter=FAST"]).compose.denoise_prefilter == "FAST"
    with pytest.raises(ConfigError, match="mesh_cache must be one of zstd, raw, off"):
        load_config(overrides=["compose.mesh_cache=lz4"])
    assert load_config(overrides=["compose.mesh_cache=off"]).compose.mesh_cache == "off"
    assert load_config(overrides=["split.train_fraction=2.0"]).split.fractions[0] == pytest.approx(2.0 / 2.3)


def test_cli_builds_the_config_once_with_command_options_last():
    from mixcount.commands.common import AppState
    from mixcount.errors import MixcountError

    st = AppState(config_files=[Path("quick")], overrides=["compose.samples=8", "compose.seed=3"])
    cfg = st.config(values={"compose.samples": 2, "compose.split": None})
    assert (cfg.compose.samples, cfg.compose.seed, cfg.compose.split) == (2, 3, "train")  # None = not given
    assert st.config() is cfg
    with pytest.raises(MixcountError, match="first config"):
        st.config(values={"compose.samples": 3})


def test_the_old_render_section_is_refused_with_the_new_names(tmp_path) -> None:
    """``[render]`` became ``[canonical_render]`` (issue 36): an old file or ``--set`` is refused with a
    message that names the new keys, not silently ignored or reported as unknown."""
    import pytest

    from mixcount.errors import ConfigError

    with pytest.raises(ConfigError, match=r"'render' .* is now 'canonical_render'.*canonical_render\.samples"):
        load_config([], ["render.samples=2"])
    old = tmp_path / "old.toml"
    old.write_text("[render]\nresolution = 64\nsamples = 2\n")
    with pytest.raises(ConfigError, match=r"canonical_render\.resolution, canonical_render\.samples"):
        load_config([old])
    assert load_config([], ["canonical_render.samples=2"]).canonical_render.samples == 2
