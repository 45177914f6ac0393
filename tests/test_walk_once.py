"""Ingest walks each real folder once: symbolic-link loops and repeated link targets are read once and
said, never hang or multiply objects; names that cannot be paths here (control characters, bytes that
are not UTF-8) make their objects broken with the reason. Checked on small libraries and on mirrors of
real package trees (PyPI wheels, Debian packages) with loops added at every level."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

from mixcount.catalog.ingest import ingest_paths
from mixcount.catalog.layouts.discovery import discover
from mixcount.config import load_config
from tests.public_packages import deb_tree, wheel_tree

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def ball(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.creation.icosphere(subdivisions=1, radius=0.03).export(path)
    return path


def walked(root: Path, extra: tuple[Path, ...] = ()) -> tuple[list, list[tuple[Path, str]]]:
    repeats: list[tuple[Path, str]] = []
    return discover([root], repeats=repeats, allowed=extra), repeats


def test_links_to_the_folder_itself_are_walked_once_and_said(tmp_path: Path) -> None:
    lib = tmp_path / "L"
    ball(lib / "balls" / "ball.glb")
    os.symlink(".", lib / "self")  # the 41 copies of one ball
    os.symlink(".", lib / "balls" / "a")  # two loops in one folder: the hang
    os.symlink(".", lib / "balls" / "b")
    os.symlink("..", lib / "balls" / "up")
    found, repeats = walked(lib)
    assert [Path(c.source_id).relative_to(lib).as_posix() for c in found] == ["balls/ball.glb"]
    assert sorted(p.relative_to(lib).as_posix() for p, _ in repeats) == ["balls/a", "balls/b", "balls/up", "self"]
    assert all("already walked (a loop" in why for _, why in repeats)


def test_a_linked_folder_keeps_its_real_path_and_outside_targets_are_refused(tmp_path: Path) -> None:
    lib, outside = tmp_path / "L", tmp_path / "elsewhere"
    ball(lib / "zz_real" / "ball.glb")
    os.symlink(lib / "zz_real", lib / "aa_alias")  # sorted first: the object still gets its real path
    ball(outside / "cups" / "cup.glb")
    os.symlink(outside, lib / "out1")  # outside the library: not followed (issue 68), said once
    os.symlink(outside / "cups", lib / "out2")
    os.symlink(lib / "zz_real" / "ball.glb", lib / "ball_link.glb")  # a model file linked beside it
    refused: list[tuple[Path, str]] = []
    repeats: list[tuple[Path, str]] = []
    found = discover([lib], repeats=repeats, refused=refused)
    paths = sorted(Path(c.source_id).relative_to(lib).as_posix() for c in found)
    assert paths == ["zz_real/ball.glb"]
    said = {p.relative_to(lib).as_posix(): why for p, why in repeats}
    assert set(said) == {"aa_alias", "ball_link.glb"}
    assert "zz_real/ball.glb" in said["ball_link.glb"]
    assert sorted(p.relative_to(lib).as_posix() for p, _ in refused) == ["out1", "out2"]
    assert all("outside the library" in why for _, why in refused)
    # allowed: the folder outside is walked as before, each real folder once
    again: list[tuple[Path, str]] = []
    found = discover([lib], repeats=again, allowed=[outside])
    assert sorted(Path(c.source_id).relative_to(lib).as_posix() for c in found) == ["out1/cups/cup.glb",
                                                                                  "zz_real/ball.glb"]
    assert "out2" in {p.relative_to(lib).as_posix() for p, _ in again}


def test_a_self_link_that_never_resolves_stays_broken(tmp_path: Path) -> None:
    lib = tmp_path / "L"
    ball(lib / "ok" / "ball.glb")
    os.symlink(lib / "Cup_B0LOOP0001_Self", lib / "Cup_B0LOOP0001_Self")  # ELOOP: nothing to walk
    found, _ = walked(lib)
    broken = {c.name: c.error for c in found if c.error}
    assert list(broken) == ["Cup_B0LOOP0001_Self"] and "unreadable folder" in broken["Cup_B0LOOP0001_Self"]


UNUSABLE = {  # folder name -> what the reason names
    "odd\nname": r"'\n'", "tab\there": r"'\t'", "cr\rname": r"'\r'", "esc\x1b[31mred": r"'\x1b'",
    "bell\x07": r"'\x07'", "sep\u2028line": r"'\u2028'", "nul\x7fdel": r"'\x7f'",
}
USABLE = ("trailing blank ", "emoji \U0001f600", "ümlaut", "[red]markup[red]", "quote'\"")


def test_names_that_cannot_be_paths_are_broken_with_the_reason(tmp_path: Path) -> None:
    lib = tmp_path / "L"
    for name in (*UNUSABLE, *USABLE):
        ball(lib / name / "cube.glb")
    ball(lib / "plain" / "nested\nfolder" / "deeper" / "cube.glb")  # the bad name above the object's folder
    raw = os.fsencode(lib) + b"/bytes\xff\xfename"
    os.mkdir(raw)
    ball(Path(os.fsdecode(raw + b"/cube.glb")))
    found, _ = walked(lib)
    errors = {Path(c.model_path).parent.name if c.model_path else c.name: c.error for c in found}
    for name, shown in UNUSABLE.items():
        assert "control characters" in errors[name] and shown in errors[name], name
        assert "\n" not in errors[name] and "\x1b" not in errors[name]
    assert "not valid UTF-8" in errors[os.fsdecode(b"bytes\xff\xfename")]
    assert "nested\\nfolder" in errors["deeper"]
    assert not any(errors[name] for name in USABLE)


@pytest.fixture(scope="module")
def bad_name_catalog(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    from mixcount.catalog.db import open_catalog

    base = tmp_path_factory.mktemp("badnames")
    lib = base / "L"
    ball(lib / "balls" / "ball.glb")
    ball(lib / "odd\nname" / "cube.glb")
    os.symlink(".", lib / "self")
    catalog = open_catalog(f"sqlite:///{base / 'catalog.db'}", data_dir=str(base / "data"))
    cfg = load_config([], ["ingest.workers=1"])
    first = ingest_paths(catalog, [lib], config=cfg)
    second = ingest_paths(catalog, [lib], config=cfg)
    yield first, second
    catalog.close()


def test_reingest_of_a_bad_name_is_unchanged_not_updated(bad_name_catalog) -> None:  # type: ignore[no-untyped-def]
    first, second = bad_name_catalog
    assert (first.total, first.new, first.broken) == (2, 1, 1)
    assert (second.new, second.updated, second.unchanged, second.broken) == (0, 0, 1, 1)
    assert "control characters" in dict(first.broken_objects)["odd\\nname"]


def test_cli_says_the_links_it_read_once(tmp_path: Path) -> None:
    lib = tmp_path / "L"
    ball(lib / "ball.glb")
    os.symlink(".", lib / "a")
    os.symlink(".", lib / "b")
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    run = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(tmp_path / "c.db"), "catalog", "ingest",
                          str(lib), "-j", "1", "--json"], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["total"] == 1 and len(summary["walked_once"]) == 2
    assert "2 link(s) lead to a folder or file already walked" in run.stderr
    assert "Traceback" not in run.stderr


def mirror_with_loops(tree: Path, dest: Path) -> int:
    """``tree`` rebuilt under ``dest`` as real folders of file links, with loops and repeated targets
    added in every folder down to depth 3; returns how many links were added."""
    added = 0
    for here, dirs, files in os.walk(tree):
        rel = Path(here).relative_to(tree)
        out = dest / rel
        out.mkdir(parents=True, exist_ok=True)
        for name in files:
            os.symlink(Path(here) / name, out / name)
        if len(rel.parts) <= 3:
            os.symlink(".", out / "zz_self")
            os.symlink(dest, out / "zz_top")
            added += 2
            if rel.parts:
                os.symlink("..", out / "aa_up")
                added += 1
            if dirs:
                os.symlink(sorted(dirs)[0], out / "aa_twin")  # sorted before the real folder it names
                added += 1
    os.symlink(tree, dest / "zz_the_package")  # the package's own folders: every file a second time
    return added


PACKAGES = [  # the first two were looked at while writing the rule; the rest held out
    pytest.param("wheel", "metaworld", id="metaworld"),
    pytest.param("deb", "prusa-slicer", id="prusa-slicer"),
    pytest.param("wheel", "genesis-world", id="genesis-world"),
    pytest.param("deb", "assimp-testmodels", id="assimp-testmodels"),
    pytest.param("wheel", "pybullet", id="pybullet", marks=pytest.mark.slow),
]


@pytest.mark.parametrize(("kind", "package"), PACKAGES)
def test_real_package_trees_with_loops_give_the_same_objects(kind: str, package: str, tmp_path: Path) -> None:
    tree, why = (wheel_tree if kind == "wheel" else deb_tree)(package)
    if tree is None:
        pytest.skip(why)
    plain, plain_repeats = walked(tree)
    added = mirror_with_loops(tree, tmp_path / "mirror")
    looped, repeats = walked(tmp_path / "mirror", (tree,))  # a mirror of links into the package: allowed

    def real(cands: list) -> list[str]:
        return sorted(os.path.realpath(c.model_path) for c in cands if c.model_path is not None)

    assert plain and not plain_repeats
    assert len(looped) == len(plain) and real(looped) == real(plain)
    assert sorted(c.error or "" for c in looped) == sorted(c.error or "" for c in plain)
    assert not any(part in ("zz_self", "zz_top", "aa_up", "aa_twin") for c in looped
                   for part in Path(c.source_id).parts)
    said = [p for p, _ in repeats if p.name.startswith(("zz_", "aa_"))]  # links inside object folders are not walked
    assert 0 < len(said) <= added
