"""``mixcount package OUT``: copy every asset file the dataset's stages use into ``OUT/assets/`` so that the
dataset opens and re-renders anywhere (docs/usd.md, "Portable datasets")."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mixcount.commands.common import console, json_option, result, state
from mixcount.errors import CatalogError, DatasetError, PackageError


def package_cmd(
    ctx: typer.Context,
    out_dir: Path = typer.Argument(..., help="Compose output folder (OUT/scenes/<scene_id>/...)."),
    search: Optional[list[Path]] = typer.Option(None, "--search", help="Folder to look in (by file name) for "
                                                "an asset whose link is broken; repeatable, searched before "
                                                "$MIXCOUNT_ASSETS."),
    json_out: bool = json_option("the report"),
) -> None:
    """Replace the links in OUT/assets/ (to the catalog's converted assets, environment maps and floor
    textures) by copies; an asset whose link is broken is found by name in --search and $MIXCOUNT_ASSETS.
    Each is checked against the libraries of the catalog that made the dataset (--db) first: one from
    outside them is refused, not copied, and said; OUT/package.json lists every file with its source."""
    from mixcount.dataset.package import package_with_catalog

    if not (out_dir / "scenes").is_dir():
        raise DatasetError(f"{out_dir} holds no scenes/ folder: nothing to package")
    st = state(ctx)
    try:
        catalog = st.catalog()
    except CatalogError as exc:
        raise PackageError(f"packaging checks every asset of {out_dir} against the libraries of the catalog that "
                           f"made it; name that catalog with --db ({exc})") from None
    try:
        report = package_with_catalog(out_dir, catalog, st.config(), search=search or ())
    finally:
        catalog.close()
    for line in report.lines():
        console.print(line, highlight=False, soft_wrap=True, markup=False)
    result(f"packaged {out_dir / 'assets'}: {len(report.copied)} copied ({report.bytes:,} bytes written), "
           f"{len(report.kept)} already copies, {len(report.searched)} found by search, {len(report.refused)} refused",
           report.to_dict(), json_out)
    report.raise_if_refused(out_dir)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("package")(package_cmd)
