"""The library root is the boundary: the one resolver every reader of a library's files goes through.

A library comes from elsewhere (a download, a scan, an image-to-3D run, a colleague's share) and a dataset
made from it gets published, so nothing outside the folder the user named may enter the catalog or a
dataset: not through a symbolic link in the tree (``ln -s / L/rootlink``), not through a reference inside a
file (a glTF image URI ``../../../secret.png`` or ``/etc/x.png``, an MTL ``map_Kd /abs/path.png``, a glTF
buffer with an absolute or ``file://`` URI, a URDF / SDF / MJCF mesh path), and not through a side file.

:class:`LibraryRoots` holds the real (symlink-resolved) folders a library may use: the folder the user
named and the extra roots the user allowed (``catalog ingest --allow-root DIR``, ``[ingest] extra_roots``).
:meth:`LibraryRoots.resolve` turns a reference into a real path inside one of them or raises
:class:`OutsideLibraryError` with the reference and the reason; :meth:`LibraryRoots.check` does the same for
a path already built (a link met in a walk). Paths are compared after ``os.path.realpath``, so ``..``
components and links anywhere on the way are followed before the test, not after. Reading textures one or
two folders above the model (robosuite's ``../../textures/soda.png``) stays right as long as those folders
are inside the library.

The rule is the same for every kind of reference; the property tests (tests/test_library_root.py) draw
references at random and check that none resolves outside the root.
"""

from __future__ import annotations

import os
import re
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator
from urllib.parse import unquote, urlsplit

from mixcount.errors import CatalogError

# a reference of another machine: a URI with a scheme other than file (http://, s3://, data: is not a file)
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
_WINDOWS_DRIVE = re.compile(r"^[A-Za-z]:[\\/]")


class OutsideLibraryError(CatalogError):
    """A reference or link leads outside the library's roots (or cannot be a local path at all).

    ``reference`` is what the file or the tree said, ``reason`` the one-line why; the object keeps what it
    can without it and is flagged with both (docs/ingest.md, "The library root is the boundary")."""

    def __init__(self, reference: str, reason: str) -> None:
        super().__init__(f"{reference}: {reason}")
        self.reference = reference
        self.reason = reason


def _real(path: str | os.PathLike[str]) -> str:
    return os.path.realpath(os.fspath(path))


def _within(real: str, root: str) -> bool:
    return real == root or real.startswith(root.rstrip(os.sep) + os.sep)


@dataclass(frozen=True)
class LibraryRoots:
    """The real folders a library's files may come from: the one named, then any the user allowed."""

    roots: tuple[str, ...]

    @classmethod
    def of(cls, root: str | os.PathLike[str], extra: Iterable[str | os.PathLike[str]] = ()) -> "LibraryRoots":
        """The boundary of a library named ``root`` (a folder, or a file whose folder is the library),
        widened by the ``extra`` roots the user allowed."""
        first = Path(_real(root))
        if first.is_file():
            first = first.parent
        extras = [_real(Path(e).expanduser()) for e in extra if str(e).strip()]
        return cls(tuple(dict.fromkeys([str(first), *extras])))

    def widened(self, *extra: str | os.PathLike[str]) -> "LibraryRoots":
        """These roots and ``extra`` folders (a staged copy's folder under the catalog's data folder)."""
        return LibraryRoots(tuple(dict.fromkeys([*self.roots, *(_real(e) for e in extra)])))

    @property
    def root(self) -> Path:
        """The folder the user named (real path)."""
        return Path(self.roots[0])

    def contains(self, path: str | os.PathLike[str]) -> bool:
        """Whether ``path``, with every link on the way followed, lies inside one of the roots."""
        real = _real(path)
        return any(_within(real, r) for r in self.roots)

    def check(self, path: str | os.PathLike[str], what: str = "path") -> Path:
        """``path`` as a real path inside the roots, or :class:`OutsideLibraryError`."""
        real = _real(path)
        if not any(_within(real, r) for r in self.roots):
            raise OutsideLibraryError(str(path), f"{what} leads outside the library ({real}); "
                                                 "allow its folder with --allow-root to use it")
        return Path(real)

    def resolve(self, reference: str, base: str | os.PathLike[str], what: str = "reference") -> Path:
        """A reference written in a library file (``base`` is the folder it is relative to) as a real path
        inside the roots. Percent-escapes and ``file://`` URIs are decoded first, as the readers decode them;
        a URI of another scheme, a Windows drive path, a NUL byte or an empty reference is refused."""
        ref = reference
        if "\x00" in ref:
            raise OutsideLibraryError(repr(reference), f"{what} holds a NUL byte")
        if not ref.strip():
            raise OutsideLibraryError(repr(reference), f"{what} is empty")
        if ref.lower().startswith("file:"):
            parts = urlsplit(ref)
            if parts.netloc not in ("", "localhost"):
                raise OutsideLibraryError(reference, f"{what} names another machine ({parts.netloc})")
            ref = unquote(parts.path)
        elif _WINDOWS_DRIVE.match(ref):
            raise OutsideLibraryError(reference, f"{what} is a Windows drive path, outside any library here")
        elif _SCHEME.match(ref):
            raise OutsideLibraryError(reference, f"{what} is a URI of another scheme, not a library file")
        else:
            ref = unquote(ref)
        if "\x00" in ref:
            raise OutsideLibraryError(repr(reference), f"{what} holds a NUL byte")
        try:
            return self.check(Path(base) / ref, what)
        except OutsideLibraryError as exc:
            raise OutsideLibraryError(reference, exc.reason) from None


# --------------------------------------------------------------------------- the boundary of one walk

_CURRENT: ContextVar[tuple[LibraryRoots, list[tuple[Path, str]]] | None] = ContextVar("library_roots", default=None)


@contextmanager
def bounded(roots: LibraryRoots, refused: list[tuple[Path, str]] | None = None) -> Iterator[LibraryRoots]:
    """Within this block :func:`current` is ``roots``: the folder listings of the layouts
    (:func:`mixcount.catalog.layouts.candidates.scan_folder`) leave out links that lead outside it, and
    :func:`mixcount.frame.load_model` reads no reference outside it. What was refused is appended to
    ``refused`` as (path, reason), once per path."""
    token = _CURRENT.set((roots, refused if refused is not None else []))
    try:
        yield roots
    finally:
        _CURRENT.reset(token)


def current() -> LibraryRoots | None:
    """The roots of the walk or ingest step under way (:func:`bounded`), None outside one."""
    here = _CURRENT.get()
    return here[0] if here else None


def refuse(path: Path, reason: str) -> None:
    """Note a link or file refused by the current walk (said once per path in the ingest summary)."""
    here = _CURRENT.get()
    if here is not None and all(p != path for p, _r in here[1]):
        here[1].append((path, reason))


def refusal(path: str | os.PathLike[str], what: str) -> str | None:
    """Why ``path`` may not be read in the current walk (its real path leaves the roots), noted once;
    None when it may (or outside a walk)."""
    roots = current()
    if roots is None:
        return None
    try:
        roots.check(path, what)
    except OutsideLibraryError as exc:
        refuse(Path(path), exc.reason)
        return exc.reason
    return None


def reference_refusal(reference: str | None, base: str | os.PathLike[str], what: str) -> str | None:
    """Why a path written in a description (a URDF / SDF / MJCF mesh ``filename``) leads outside the roots
    of the current walk (None when it does not, when it is a package URI such as ``package://`` or
    ``model://``, matched by file name only, or outside a walk)."""
    roots = current()
    if roots is None or not reference or (_SCHEME.match(reference) and not reference.lower().startswith("file:")
                                          and not _WINDOWS_DRIVE.match(reference)):
        return None
    try:
        roots.resolve(reference, base, what)
    except OutsideLibraryError as exc:
        return exc.reason
    return None
