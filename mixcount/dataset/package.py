"""Datasets that open anywhere: the files a dataset's stages use live under ``OUT/assets/`` and every
recorded path is relative (docs/usd.md, "Portable datasets").

Layout under ``OUT/assets/``:

- ``<hash>.usdc``, ``<hash>_tex/``, ``<hash>_collision.usdc``: the converted catalog assets
  (:mod:`mixcount.usd.assets`) the stages reference;
- ``environments/<file>``: the environment maps of the dome lights (ingested HDRIs, bpy's bundled ones);
- ``materials/<digest>/<file>``: the texture maps of PBR floors;
- ``sources/<hash>/<file>``: a USD source model that a wrapped asset references.

Stages reference these by paths relative to the stage (``@../../assets/<hash>.usdc@``), so a dataset
opens wherever it is copied. While composing, each entry is a *relative symbolic link* to the catalog's
file (no copy, no absolute path; the Blender worker resolves links, so its mesh cache stays in the
catalog). :func:`package_assets` (``mixcount package OUT`` or ``compose --package-assets``) turns every
link into a real copy, so the dataset holds everything needed to re-render it. A dataset moved before it
was packaged finds its files again through ``MIXCOUNT_ASSETS`` (folders holding the catalog's
``usd_assets`` and the environment maps, ``:``-separated), which ``package`` searches by file name (in each
folder and the folders right under it: ``usd_assets/<catalog>/``).

Recorded paths (``metadata.json``, the spec in each stage's ``customLayerData``) are written by
:func:`mixcount.usd.portable.portable_paths` (``assets/<name>``, ``bpy:<path>``, ``source:<file name>``).

Only library files get in (issue 68; :mod:`mixcount.dataset.sources`): with the catalog that made the
dataset (``compose --package-assets``, ``mixcount package --db CATALOG``: :func:`package_with_catalog`) each
entry is checked first, and one whose object's model or a file it names lies outside its library - or
that is no file of the catalog at all - is refused: not copied, its link taken out, one line naming it.
``OUT/package.json`` lists every packaged file with its bytes and its sources (library name, id and path
relative to the library: no absolute path) and the refused entries; the report's ``bytes`` is the sum of
the files this call wrote, measured on disk after every rewrite.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from glob import escape as glob_escape
from pathlib import Path
from typing import Any, Iterable, Optional

from mixcount.atomic import atomic_path, write_text_atomic
from mixcount.errors import CompositionError, PackageError
from mixcount.usd.portable import ASSETS_DIR, SOURCES_DIR, PathRoots, portable_paths

SEARCH_ENV = "MIXCOUNT_ASSETS"
STAGE_SUFFIXES = (".usda", ".usdc", ".usd")
PACKAGE_LIST = "package.json"  # OUT/package.json: every packaged file with its sources, the refused entries
PACKAGE_LIST_VERSION = 1


# ------------------------------------------------------------------------------------ packaging


@dataclass
class PackageReport:
    """What :func:`package_assets` did: entries copied, already real files, found via the search path."""

    copied: list[str] = field(default_factory=list)
    kept: list[str] = field(default_factory=list)
    searched: list[str] = field(default_factory=list)
    rewritten: list[str] = field(default_factory=list)
    bytes: int = 0  # of the files this call wrote (copies, rewritten layers, USD sources), measured on disk
    refused: list[tuple[str, str]] = field(default_factory=list)  # (entry, the one line said)
    files: list[dict[str, Any]] = field(default_factory=list)  # OUT/package.json's "files"
    checked: bool = False  # the entries were checked against the catalog's libraries

    def to_dict(self) -> dict[str, Any]:
        return {"copied": len(self.copied), "kept": len(self.kept), "found_by_search": len(self.searched),
                "layers_rewritten": len(self.rewritten), "bytes": self.bytes, "refused": len(self.refused),
                "refused_entries": [e for e, _line in self.refused], "checked": self.checked}

    def lines(self) -> list[str]:
        """One line per refused entry (what was not copied and why)."""
        return [f"refused {line}: not copied into the dataset" for _entry, line in self.refused]

    def raise_if_refused(self, out_dir: Path) -> None:
        """A :class:`PackageError` when an entry was refused (each was said in one line)."""
        if self.refused:
            raise PackageError(f"{len(self.refused)} asset entr{'y' if len(self.refused) == 1 else 'ies'} of {out_dir} "
                               "refused (listed above): they come from outside the catalog's libraries, and the "
                               "scenes using them no longer open whole; re-ingest the objects' libraries (or allow "
                               "the folder: [ingest] extra_roots) and compose those scenes again")


def search_roots(extra: Iterable[Path] = ()) -> list[Path]:
    """Folders searched for an entry whose link is broken: ``extra``, then ``$MIXCOUNT_ASSETS``, then the
    bundled HDRIs of this machine's bpy (an environment map of bpy's is found on any machine with bpy)."""
    env = [Path(p) for p in os.environ.get(SEARCH_ENV, "").split(os.pathsep) if p]
    bundled: list[Path] = []
    try:
        from mixcount.scene.bundled_environments import bundled_hdri_dir

        bundled = [bundled_hdri_dir()]
    except Exception:  # no bpy here: only the given folders
        pass
    return [Path(p) for p in extra] + env + bundled


def _find(rel: str, roots: list[Path]) -> Optional[Path]:
    """The first of ``root/rel``, ``root/<name>`` and ``root/<one folder>/<name>`` that exists: a catalog's
    ``usd_assets`` folder holds one folder per catalog (``usd_assets/<catalog>/``), so a search path naming
    ``usd_assets`` itself finds them too."""
    name = Path(rel).name
    for root in roots:
        for cand in (root / rel, root / name):
            if cand.exists():
                return cand
    for root in roots:
        for cand in sorted(root.glob(f"*/{glob_escape(name)}")) if root.is_dir() else []:
            return cand
    return None


def _copy(src: Path, dest: Path) -> int:
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.copy")
    if tmp.is_dir():
        shutil.rmtree(tmp)
    if src.is_dir():
        shutil.copytree(src, tmp, symlinks=False)
        size = sum(f.stat().st_size for f in tmp.rglob("*") if f.is_file())
    else:
        shutil.copyfile(src, tmp)
        size = tmp.stat().st_size
    if dest.is_symlink() or dest.is_file():
        dest.unlink()
    elif dest.is_dir():
        shutil.rmtree(dest)
    os.replace(tmp, dest)
    return size


def _referenced_entries(out_dir: Path) -> set[str]:
    """Entries of OUT/assets the stages name (a moved, never-packaged dataset may have lost its links)."""
    from pxr import Sdf

    assets = (out_dir / ASSETS_DIR).absolute()
    found: set[str] = set()
    for stage in sorted((out_dir / "scenes").glob("*/*.usda")):
        layer = Sdf.Layer.OpenAsAnonymous(str(stage))
        if layer is None:
            continue
        for ref in layer.GetCompositionAssetDependencies() + _asset_values(layer):
            p = Path(os.path.normpath(stage.parent.absolute() / ref)) if not Path(ref).is_absolute() else Path(ref)
            if assets in p.parents:
                rel = p.relative_to(assets).as_posix()
                found.add(rel)
                if rel.endswith(".usdc") and not rel.endswith("_collision.usdc"):
                    found.add(rel[: -len(".usdc")] + "_tex")
    return found


def _asset_values(layer: Any) -> list[str]:
    """Asset-valued attribute defaults of a layer (the dome light's texture, floor textures)."""
    from pxr import Sdf

    out: list[str] = []

    def visit(path: Any) -> None:
        if not path.IsPropertyPath():
            return
        spec = layer.GetPropertyAtPath(path)
        value = getattr(spec, "default", None)
        if isinstance(value, Sdf.AssetPath) and value.path:
            out.append(value.path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return out


def _entry_files(assets: Path, rel: str) -> list[tuple[str, int]]:
    """(posix path under OUT, bytes) of every regular file of the entry ``assets/<rel>`` (a file or a folder)."""
    entry = assets / rel
    if entry.is_symlink():
        return []
    files = [entry] if entry.is_file() else sorted(f for f in entry.rglob("*") if f.is_file() and not f.is_symlink())
    return [(f"{ASSETS_DIR}/{f.relative_to(assets).as_posix()}", f.stat().st_size) for f in files]


def _remove_entry(dest: Path) -> None:
    """A refused entry taken out of the dataset (a link, or a copy an older, unchecked package made)."""
    if dest.is_symlink() or dest.is_file():
        dest.unlink()
    elif dest.is_dir():
        shutil.rmtree(dest)


def _sanitize_layer(path: Path, out_dir: Path, roots: PathRoots, report: PackageReport) -> None:
    """A copied asset layer: its customLayerData paths made portable; a reference to a USD source model
    outside the dataset copied into ``sources/`` and re-pointed relatively."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(path))
    if layer is None:
        raise PackageError(f"{path}: not a USD layer")
    changed = False
    data = dict(layer.customLayerData)
    portable = portable_paths(data, roots)
    if portable != data:
        layer.customLayerData = portable
        changed = True
    for prim in [layer.GetPrimAtPath(p) for p in ("/Asset/Source",)]:
        if prim is None:
            continue
        items = list(prim.referenceList.prependedItems)
        new_items = []
        for ref in items:
            src = Path(ref.assetPath)
            if src.is_absolute():
                rel = f"{SOURCES_DIR}/{path.stem}/{src.name}"
                dest = out_dir / ASSETS_DIR / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                if not dest.exists():
                    _copy(src, dest)
                    report.copied.append(rel)
                ref = Sdf.Reference(Path(os.path.relpath(dest, path.parent)).as_posix(), ref.primPath,
                                    ref.layerOffset, ref.customData)
                changed = True
            new_items.append(ref)
        prim.referenceList.prependedItems = new_items
    if changed:
        # exported whole to a new file: saving a .usdc in place appends, and its old strings (the
        # generating machine's paths) would stay in the file
        with atomic_path(path) as tmp:
            if not layer.Export(str(tmp)):
                raise PackageError(f"could not write {path}")
        report.rewritten.append(path.name)


def package_with_catalog(out_dir: Path, catalog: Any, config: Any, *, search: Iterable[Path] = ()) -> PackageReport:
    """:func:`package_assets` of a dataset composed from ``catalog``: each entry checked against the
    catalog's libraries first (``config.ingest.extra_roots`` as configured now widen them)."""
    from mixcount.dataset.settings import catalog_identity, read_settings
    from mixcount.dataset.sources import CatalogSources

    try:
        recorded = {str(v.get("settings", {}).get("catalog")) for v in read_settings(Path(out_dir))["variants"]
                    if v.get("settings", {}).get("catalog")}
    except CompositionError:  # a damaged settings.json: nothing recorded to hold the catalog against
        recorded = set()
    given = catalog_identity(catalog.url)
    if recorded and given not in recorded:  # another catalog cannot vouch, and must not take copies out
        raise PackageError(f"{out_dir} was composed from the catalog {', '.join(sorted(recorded))} (settings.json), not "
                           f"{given}: packaging checks each asset against the libraries of the catalog that made the "
                           "dataset; name that catalog with --db; nothing was changed")
    return package_assets(out_dir, search=[*search, Path(catalog.usd_assets_dir)],
                          assets_dirs=[Path(catalog.usd_assets_dir)],
                          sources=CatalogSources(catalog, config.ingest.extra_roots),
                          take_out_copies=bool(recorded))  # unproven catalog: a refused copy is said, kept


def package_assets(out_dir: Path, *, search: Iterable[Path] = (), assets_dirs: Iterable[Path] = (),
                   sources: Any = None, take_out_copies: bool = True) -> PackageReport:
    """Make ``OUT/assets/`` hold real copies of every file the dataset's stages use.

    Each symbolic link is replaced by a copy of its target; an entry whose link is broken, or that a
    stage names and that is missing, is looked for by name in ``search`` and ``$MIXCOUNT_ASSETS``. Copied
    USD layers get portable customLayerData. ``sources`` (a :class:`mixcount.dataset.sources.CatalogSources`;
    None: nothing checked, for datasets built without a catalog) refuses what did not come from the
    libraries (module docstring); a refused entry (a link, or a copy an older package made) is taken out
    only with ``take_out_copies`` (the catalog is known to be the dataset's: settings.json names it), else
    it is said and left as it was. Writes ``OUT/package.json``. Raises :class:`PackageError` naming every
    entry found nowhere (what was copied before stays; a rerun finishes the job)."""
    out_dir = Path(out_dir)
    assets = out_dir / ASSETS_DIR
    roots = search_roots(search)
    path_roots = PathRoots(out_dir, tuple(Path(a) for a in assets_dirs) + tuple(roots))
    report = PackageReport(checked=sources is not None)
    verdicts: dict[str, Any] = {}
    wanted = _referenced_entries(out_dir) if (out_dir / "scenes").is_dir() else set()
    present: set[str] = set()
    if assets.is_dir():
        for entry in sorted(assets.rglob("*")):
            rel = entry.relative_to(assets).as_posix()
            if entry.name.startswith(".") or any(rel.startswith(p + "/") for p in present if (assets / p).is_dir()):
                continue
            if entry.is_symlink() or entry.is_file() or (entry.is_dir() and rel.endswith("_tex")):
                present.add(rel)
    missing: list[str] = []
    for rel in sorted(present | wanted):
        dest = assets / rel
        if dest.exists() and not dest.is_symlink():
            if _refused(sources, rel, dest, dest if take_out_copies else None, report, verdicts):
                continue
            report.kept.append(rel)
            continue
        src: Optional[Path] = dest.resolve() if dest.is_symlink() and dest.exists() else None
        if src is None:
            src = _find(rel, roots)
            if src is not None:
                report.searched.append(rel)
        if src is None:
            if rel.endswith("_tex"):
                continue  # an asset without textures has no texture folder
            missing.append(rel)
            continue
        if _refused(sources, rel, src, dest if take_out_copies else None, report, verdicts):
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        _copy(src, dest)
        report.copied.append(rel)
        if dest.suffix in STAGE_SUFFIXES:
            _sanitize_layer(dest, out_dir, path_roots, report)
    _write_list(out_dir, report, verdicts)
    if missing:
        raise PackageError(f"{len(missing)} asset(s) of {out_dir} found nowhere (links broken and not in "
                           f"${SEARCH_ENV} {os.environ.get(SEARCH_ENV, '')!r}): {', '.join(missing[:10])}")
    return report


def _refused(sources: Any, rel: str, target: Optional[Path], dest: Optional[Path], report: PackageReport,
             verdicts: dict[str, Any]) -> bool:
    """Whether ``rel`` is refused by ``sources`` (then it is said, and ``dest`` taken out of the dataset)."""
    if sources is None:
        return False
    verdict = sources.verdict(rel, target)
    verdicts[rel] = verdict
    if verdict.ok:
        return False
    if dest is not None:
        _remove_entry(dest)
    report.refused.append((rel, str(verdict.refused)))
    return True


def _write_list(out_dir: Path, report: PackageReport, verdicts: dict[str, Any]) -> None:
    """``OUT/package.json``: every packaged file (bytes, entry, whether this call wrote it, object ids,
    sources), the refused entries;
    ``report.bytes`` = the bytes of the files this call wrote, as they lie on disk now."""
    assets = out_dir / ASSETS_DIR
    written = set(report.copied)
    files: list[dict[str, Any]] = []
    for rel in sorted(set(report.kept) | written):
        verdict = verdicts.get(rel)
        if verdict is None and rel.startswith(f"{SOURCES_DIR}/"):  # a USD source copied with its asset layer
            verdict = verdicts.get(f"{rel.split('/')[1]}.usdc")
        for path, size in _entry_files(assets, rel):
            files.append({"file": path, "bytes": size, "entry": rel, "written": rel in written,
                          "object_ids": list(verdict.object_ids) if verdict is not None else [],
                          "sources": [src.to_dict() for src in verdict.sources] if verdict is not None else []})
            if rel in written:
                report.bytes += size
    report.files = files
    refused = [{"entry": rel, "object_ids": list(verdicts[rel].object_ids), "why": verdicts[rel].why}
               for rel, _line in report.refused]
    doc = {"version": PACKAGE_LIST_VERSION, "checked_against_libraries": report.checked,
           "bytes": sum(f["bytes"] for f in files), "files": files, "refused": refused}
    write_text_atomic(out_dir / PACKAGE_LIST, json.dumps(doc, indent=1, ensure_ascii=False) + "\n")
