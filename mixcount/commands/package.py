"""``mixcount package OUT``: copy every asset file the dataset's stages use into ``OUT/assets/`` so that the
dataset opens and re-renders anywhere (docs/usd.md, "Portable datasets")."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from mixcount.commands.common import json_option, result
from mixcount.errors import DatasetError


def package_cmd(
    out_dir: Path = typer.Argument(..., help="Compose output folder (OUT/scenes/<scene_id>/...)."),
    search: Optional[list[Path]] = typer.Option(None, "--search", help="Folder to look in (by file name) for "
                                                "an asset whose link is broken; repeatable, searched before "
                                                "$MIXCOUNT_ASSETS."),
    json_out: bool = json_option("the report"),
) -> None:
    """Replace the links in OUT/assets/ (to the catalog's converted assets, environment maps and floor
    textures) by copies; an asset whose link is broken is found by name in --search and $MIXCOUNT_ASSETS."""
    from mixcount.dataset.package import package_assets

    if not (out_dir / "scenes").is_dir():
        raise DatasetError(f"{out_dir} holds no scenes/ folder: nothing to package")
    report = package_assets(out_dir, search=search or ())
    result(f"packaged {out_dir / 'assets'}: {len(report.copied)} copied ({report.bytes / 1e6:.1f} MB), "
           f"{len(report.kept)} already copies, {len(report.searched)} found by search", report.to_dict(), json_out)


def register(app: typer.Typer, catalog_app: typer.Typer) -> None:
    app.command("package")(package_cmd)
