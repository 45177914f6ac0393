"""Property tests of the one resolver of a library's files (mixcount/library_root.py, issue 68 item 8):
references drawn at random (``..``, ``.``, links inside and out, absolute paths, ``file://`` URIs,
percent-escapes, a sibling folder whose name extends the root's) never resolve outside the root, and
every reference whose file lies inside resolves to exactly that file, compared with an oracle built
on ``os.path`` (no code of the resolver)."""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import quote, unquote

import pytest
from fuzz_settings import fuzz
from hypothesis import example, given
from hypothesis import strategies as st

from mixcount.library_root import LibraryRoots, OutsideLibraryError


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """top/lib (the root: a/b/file.png, a/x.png, links in and out), top/lib_evil (a sibling whose name
    extends the root's), top/outside/secret.png."""
    top = tmp_path_factory.mktemp("roots")
    lib = top / "lib"
    (lib / "a" / "b").mkdir(parents=True)
    (lib / "a" / "b" / "file.png").write_bytes(b"x")
    (lib / "a" / "x.png").write_bytes(b"x")
    (top / "lib_evil").mkdir()
    (top / "lib_evil" / "x.png").write_bytes(b"x")
    (top / "outside").mkdir()
    (top / "outside" / "secret.png").write_bytes(b"x")
    os.symlink(lib / "a", lib / "link_in")
    os.symlink(top / "outside", lib / "link_out")
    os.symlink(top / "outside" / "secret.png", lib / "a" / "tex_out.png")
    os.symlink(lib / "link_out", lib / "chain")  # inside -> inside -> outside
    return top


SEGMENTS = st.sampled_from(["..", ".", "a", "b", "file.png", "x.png", "secret.png", "tex_out.png", "link_in",
                            "link_out", "chain", "lib", "lib_evil", "outside", ""])


@st.composite
def references(draw: st.DrawFn, top: Path) -> str:
    path = "/".join(draw(st.lists(SEGMENTS, min_size=1, max_size=7)))
    form = draw(st.sampled_from(["relative", "absolute", "file", "escaped", "escaped_file"]))
    if form == "absolute":
        return f"{top}/{path}"
    if form == "file":
        return "file://" + f"{top}/{path}"
    if form == "escaped":
        return quote(path, safe="") if draw(st.booleans()) else path.replace("/", "%2F").replace(".", "%2e")
    if form == "escaped_file":
        return "file://" + quote(f"{top}/{path}")
    return path


def _oracle(reference: str, base: Path, root: Path) -> str | None:
    """The real file a reference names when it lies inside ``root`` (else None): os.path only."""
    ref = unquote(reference[len("file://"):] if reference.startswith("file://") else reference)
    real = os.path.realpath(os.path.join(base, ref))
    inside = os.path.commonpath([real, str(root)]) == str(root)
    return real if inside else None


def test_the_root_and_its_extension_are_told_apart(tree: Path) -> None:
    roots = LibraryRoots.of(tree / "lib")
    assert roots.resolve("a/x.png", tree / "lib") == (tree / "lib" / "a" / "x.png").resolve()
    for ref in ("../lib_evil/x.png", str(tree / "lib_evil" / "x.png"), "link_out/secret.png", "a/tex_out.png",
                "chain/secret.png", (tree / "outside" / "secret.png").as_uri(), "..%2Flib_evil%2Fx.png",
                "http://example.com/x.png", "C:\\x.png", "a/x.png\x00", ""):
        with pytest.raises(OutsideLibraryError):
            roots.resolve(ref, tree / "lib")
    wider = LibraryRoots.of(tree / "lib", [tree / "outside"])
    assert wider.resolve("link_out/secret.png", tree / "lib") == (tree / "outside" / "secret.png").resolve()


@fuzz(400)
@example(reference="../lib_evil/x.png", depth=0)
@example(reference="link_in/../../outside/secret.png", depth=0)
@given(reference=st.deferred(lambda: references(Path("/TOP"))), depth=st.integers(0, 2))
def test_no_reference_resolves_outside_and_inside_ones_find_their_file(tree: Path, reference: str,
                                                                       depth: int) -> None:
    reference = reference.replace("/TOP", str(tree))
    root = (tree / "lib").resolve()
    base = root / "/".join(["a", "b"][:depth]) if depth else root
    roots = LibraryRoots.of(root)
    expected = _oracle(reference, base, root)
    try:
        got = roots.resolve(reference, base)
    except OutsideLibraryError as exc:
        assert exc.reason and "\n" not in exc.reason
        assert expected is None or "\x00" in reference or not reference.strip(), (reference, expected)
        return
    assert os.path.commonpath([str(got), str(root)]) == str(root), (reference, got)
    assert str(got) == expected, (reference, got, expected)
