"""CAD parts through the user's commands: per part the colours its STEP file holds, the colours of its
canonical render, its caption, category and the unit shown (issue 70 items 1 and 6).

    .venv/bin/python bench/cad_colours.py PART.step ... [--resolution 128] [--keep DIR]

Each file goes into a folder of its own, named by its file name (as a KiCad user exports parts), and the
library is ingested, rendered (real bpy) and captioned (stub) with the ``quick`` config. One row per part
on stdout (tab-separated): the part, the file's distinct colours (named by :func:`name_rgb`), the render's
colours with their share of the object's pixels (``colours_from_render``: those over 12 %), the short
caption, the category and the unit ``catalog list`` shows.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

_COLOUR = re.compile(r"COLOUR_RGB\s*\(\s*'[^']*'\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)", re.I)


def file_colours(path: Path) -> list[str]:
    from mixcount.captions.colours import name_rgb

    values = {tuple(round(float(v), 3) for v in m) for m in _COLOUR.findall(path.read_text(errors="replace"))}
    return sorted({name_rgb(tuple(int(round(c * 255)) for c in v)) for v in values})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("steps", nargs="*", type=Path)
    parser.add_argument("--smoke", action="store_true",
                        help="the smoke run of tests/test_benches.py: one coloured STEP part of kicad-demos, 32 px")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--keep", type=Path, default=None, help="work in this folder and keep it (renders)")
    args = parser.parse_args(argv)
    if args.smoke:
        sys.path.insert(0, str(ROOT / "tests"))
        from public_packages import deb_tree  # type: ignore[import-not-found]

        root, why = deb_tree("kicad-demos")
        if root is None:
            print(json.dumps({"skipped": why}))
            return 0
        args.steps, args.resolution = [root / "usr/share/kicad/demos/stickhub/3dmodels/APHB1608.step"], 32
    if not args.steps:
        parser.error("name at least one STEP file")
    from sqlalchemy import select

    from mixcount.captions.colours import render_pixels, summarise
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CaptionSet, CatalogObject
    from mixcount.catalog.units import shown_unit, units_reason_of
    from mixcount.cli import main as cli
    from mixcount.curation.renders import canonical_render_path

    work = args.keep or Path(tempfile.mkdtemp(prefix="cad_colours_"))
    lib = work / "lib"
    for step in args.steps:
        (lib / step.stem).mkdir(parents=True, exist_ok=True)
        shutil.copy(step, lib / step.stem / step.name)
    db = ["--db", str(work / "catalog.db"), "--config", "quick", "--set", f"canonical_render.resolution={args.resolution}"]
    with contextlib.redirect_stdout(io.StringIO()):
        for step in (["catalog", "ingest", str(lib), "--workers", "1"], ["catalog", "render"], ["catalog", "caption"]):
            if cli([*db, *step]) not in (0, 1):
                raise SystemExit(f"{' '.join(step)} failed")
    cat = open_catalog(db[1], data_dir="")
    print("part\tin file\tin render (share)\tshort caption\tcategory\tunit")
    rows = []
    try:
        with cat.session() as s:
            for obj in s.scalars(select(CatalogObject).order_by(CatalogObject.name)):
                render = canonical_render_path(s, obj.id)
                shares = ""
                if render is not None:
                    summary = summarise(render_pixels(render), source="render", min_share=0.05, max_names=5)
                    shares = ", ".join(f"{n} {p:.0%}" for n, p in zip(summary.names, summary.shares))
                short = next((cs.short for cs in s.scalars(select(CaptionSet).where(
                    CaptionSet.object_id == obj.id, CaptionSet.active.is_(True)))), "")
                step = lib / obj.name / f"{obj.name}.step"
                unit = shown_unit(obj.source_units, units_reason_of(obj.metadata_json))
                print(f"{obj.name}\t{', '.join(file_colours(step)) if step.is_file() else '?'}\t{shares}\t{short}\t"
                      f"{obj.category}\t{unit}")
                rows.append({"part": obj.name, "file_colours": len(file_colours(step)) if step.is_file() else 0,
                             "render_colours": len(shares.split(", ")) if shares else 0, "unit": unit,
                             "category": obj.category})
    finally:
        cat.close()
    print(json.dumps({"work": str(work)}), file=sys.stderr)
    print(json.dumps({"parts": len(rows), "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
