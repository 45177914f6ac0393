"""The one compose entry (mixcount/run/compose_entry.py): the API makes the checks the CLI makes, before
anything is opened or written (issue 58)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest


class NoCatalog:
    """A catalog that must not be touched: a check that fails first never opens it."""

    url = "sqlite:///nowhere.db"
    usd_assets_dir = "/nowhere"

    def session(self) -> Any:
        raise AssertionError("the catalog was opened before the checks")


def test_the_api_refuses_a_bad_count_target_before_opening_the_catalog(tmp_path: Path) -> None:
    import mixcount
    from mixcount.errors import ConfigError

    out = tmp_path / "out"
    with pytest.raises(ConfigError, match="count target 'nonsense'"):
        mixcount.compose(NoCatalog(), out, n=1, config=["quick"], overrides=["scene.count_target=nonsense"])  # type: ignore[arg-type]
    assert not out.exists()


def test_the_job_names_the_objects_of_each_split_when_its_split_is_empty(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    from mixcount.config import load_config
    from mixcount.errors import CompositionError
    from mixcount.run.compose_entry import ComposeJob

    class Session:
        def __enter__(self) -> "Session":
            return self

        def __exit__(self, *exc: object) -> None:
            return None

    class Catalog(NoCatalog):
        def session(self) -> Any:
            return Session()

    pool = [type("Obj", (), {"split": s})() for s in ("train", "train", "test")]
    import mixcount.catalog.pool_loader as loader

    monkeypatch.setattr(loader, "load_pool", lambda session, palette: pool)
    monkeypatch.setattr(loader, "load_environments", lambda session: [])
    monkeypatch.setattr(loader, "load_materials", lambda session: [])
    job = ComposeJob.checked(load_config(["quick"], values={"compose.split": "val"}), n=1, out_dir=tmp_path / "out")
    with pytest.raises(CompositionError, match=r"split 'val' \(active objects per split: train 2, val 0, test 1\)"):
        job.run(Catalog())
    with pytest.raises(CompositionError, match="split 'val'"):
        job.plan(Catalog())
    assert not (tmp_path / "out").exists()
