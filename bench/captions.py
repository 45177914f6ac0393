"""Captions a person would write: issue 50's figures on a capture-like pool with person-written names.

Usage: .venv/bin/python bench/captions.py [--layouts folder,dtc,obj] [--resolution 64] [--samples 2]
                                         [--no-render] [--sheet docs/images/captions_sheet.png --sheet-n 20]
                                         [--work DIR] [--smoke]

For each layout, tests/named_library.py's library (59 objects: person-written names with source tags, ids
and broad categories, textured and vertex-coloured meshes, recolour pairs, the issue's cases: "Orange juice
carton" printed brown and gold, "Black bowl" beside a "White bowl", "Ice-cream dispenser", "Stanford
bunny", pybullet's duck as an OBJ whose .mtl says Kd 0.64 beside its texture, and DTC folder names with no
name) is written in a temporary folder, then through the CLI: `catalog ingest` -> `catalog filter` ->
`catalog render` (canonical renders at --resolution / --samples) -> `catalog caption` (the default:
collisions resolved, then deduplicated) -> `catalog list --json`. The render's dominant colour is named
over its lit side (:func:`mixcount.captions.colours.lit_colours_from_render`; also given over every pixel). Prints per layout, to stderr, the
figures and, to stdout, one JSON line:
{"layout", "active", "mesh_facts", "absolute_sizes", "name_colour_share", "compound_share", "noun_share",
 "excluded_by_collision", "textured", "textured_agree", "disagree": [...], "seconds"}
`--sheet PATH` also draws twenty captions (seeded random choice over every layout's active objects) beside
their canonical renders, the three tiers under each image (docs/captions.md shows it).
"""

from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from named_library import build_named_library, caption_figures, rows_from_list_json  # noqa: E402

from mixcount.captions.colours import colour_words_in, colours_agree, colours_from_render, lit_colours_from_render  # noqa: E402


def _cli(db: Path, *args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "mixcount", "--db", str(db), *args], capture_output=True,
                          text=True, cwd=ROOT)
    if done.returncode != 0:
        raise SystemExit(f"mixcount {' '.join(args)} failed: {done.stderr[-2000:]}")
    return done.stdout


def _render_paths(db: Path) -> dict[int, Path]:
    from sqlalchemy import select

    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CatalogObject
    from mixcount.curation.renders import canonical_render_path

    catalog = open_catalog(f"sqlite:///{db}", data_dir=str(db.parent / "data"))
    try:
        with catalog.session() as s:
            out = {}
            for oid in s.scalars(select(CatalogObject.id)):
                found = canonical_render_path(s, oid)
                if found:
                    out[int(oid)] = Path(found)
            return out
    finally:
        catalog.close()


SMOKE = {"red_coffee_mug", "juice_carton", "black_bowl", "white_bowl", "ice_cream_dispenser", "duck_obj",
         "block_cube", "block_plank", "traffic_cone", "siamese_cat"}  # not the 100k-face bunny: 10 s of the suite


def run_layout(layout: str, work: Path, *, render: bool, resolution: int, samples: int,
               only: set[str] | None = None) -> tuple[dict, list[dict]]:
    start = time.perf_counter()
    truth = build_named_library(work / "lib", layout, only)
    db = work / "catalog.db"
    _cli(db, "catalog", "ingest", str(work / "lib"), "--json")
    _cli(db, "catalog", "filter")
    if render:
        _cli(db, "--set", f"canonical_render.resolution={resolution}", "--set", f"canonical_render.samples={samples}",
             "--set", "canonical_render.denoise=false", "catalog", "render")
    summary = json.loads(_cli(db, "catalog", "caption", "--json").strip().splitlines()[-1])
    records = json.loads(_cli(db, "catalog", "list", "--json"))
    figures = caption_figures(rows_from_list_json(records), truth)
    renders = _render_paths(db) if render else {}
    by_folder = {t["folder"]: (slug, t) for slug, t in truth.items()}
    excluded = [r for r in records if r["status"] == "excluded"
                and any(f["kind"] == "caption_collision" for f in r["flags"])]
    textured = agree = agree_all = 0
    disagree: list[str] = []
    shown: list[dict] = []
    for r in records:
        if r["status"] != "active" or not r.get("captions"):
            continue
        slug, t = by_folder[Path(r["model_path"]).parent.name]
        png = renders.get(int(r["id"]))
        shown.append({"layout": layout, "slug": slug, "name": t["name"] or t["folder"], "render": png,
                      "captions": r["captions"]})
        if not (t["textured"] and png is not None):
            continue
        textured += 1
        dominant = lit_colours_from_render(png).names[:1]
        said = colour_words_in(r["captions"]["short"] + " , " + r["captions"]["concise"])
        every = colours_from_render(png).names[:1]  # over every object pixel, shadows included
        agree_all += bool(every and colours_agree(said, every[0]))
        if dominant and colours_agree(said, dominant[0]):
            agree += 1
        else:
            disagree.append(f"{slug}: render {dominant} / {r['captions']['short']!r} / {r['captions']['concise']!r}")
    out = {
        "layout": layout, "active": figures["active"], "mesh_facts": figures["mesh_facts"],
        "absolute_sizes": figures["absolute_sizes"], "name_colour_share": figures["name_colour_share"],
        "name_colours": figures["name_colours"], "compound_share": figures["compound_share"],
        "compounds": figures["compounds"], "noun_share": figures["noun_share"],
        "excluded_by_collision": len(excluded), "collision_pairs_left": summary["collision_pairs"],
        "told_apart": summary["variants_toned"], "caption_failures": summary["failed"],
        "check_warned": summary["caption_check"]["objects_warned"], "textured": textured,
        "textured_agree": agree, "textured_agree_all_pixels": agree_all, "disagree": disagree, "misses": figures["person_misses"],
        "seconds": round(time.perf_counter() - start, 1),
    }
    return out, shown


def draw_sheet(entries: list[dict], path: Path, *, n: int, seed: int, thumb: int = 128) -> list[str]:
    """A PNG of ``n`` seeded-random captions beside their renders (three tiers under each image)."""
    from PIL import Image, ImageDraw, ImageFont

    rng = random.Random(seed)
    by_slug: dict[str, list[dict]] = {}
    for e in entries:
        if e["render"] is not None:
            by_slug.setdefault(e["slug"], []).append(e)
    pick = [rng.choice(by_slug[slug]) for slug in rng.sample(sorted(by_slug), n)]  # n objects, each in one layout
    cols, cell_w, text_h = 5, 250, 150
    rows = (n + cols - 1) // cols
    sheet = Image.new("RGB", (cols * cell_w, rows * (thumb + text_h)), "white")
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default()
    names = []
    for k, e in enumerate(pick):
        x, y = (k % cols) * cell_w, (k // cols) * (thumb + text_h)
        with Image.open(e["render"]) as im:
            im = im.convert("RGB")
            im.thumbnail((thumb, thumb))
            sheet.paste(im, (x + (cell_w - im.width) // 2, y + 2))
        lines = [f"[{e['name']}]"[:44]]
        for tier, width in (("short", 40), ("concise", 40), ("detailed", 40)):
            wrapped = textwrap.wrap(f"{tier[0].upper()}: {e['captions'][tier]}", width)
            lines += wrapped[: (5 if tier == "detailed" else 2)]
        for i, line in enumerate(lines[:10]):
            draw.text((x + 4, y + thumb + 4 + 14 * i), line, fill=(0, 0, 0) if i else (90, 90, 90), font=font)
        names.append(f"{e['layout']}/{e['slug']}")
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path, optimize=True)
    return names


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", default="folder,dtc,obj")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--samples", type=int, default=2)
    parser.add_argument("--no-render", action="store_true", help="skip renders (no colour agreement figure)")
    parser.add_argument("--sheet", type=Path, default=None)
    parser.add_argument("--sheet-n", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=None, help="keep the libraries and catalogs here")
    parser.add_argument("--smoke", action="store_true",
                        help="seconds: ten of the objects (the issue's cases), the obj layout, 32 px renders")
    args = parser.parse_args()
    only = SMOKE if args.smoke else None
    if args.smoke:
        args.layouts, args.resolution, args.samples = "obj", 32, 1
    shown: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="mixcount-captions-") as scratch:
        tmp = args.work or Path(scratch)
        for layout in args.layouts.split(","):
            figures, entries = run_layout(layout, tmp / layout, render=not args.no_render,
                                          resolution=args.resolution, samples=args.samples, only=only)
            shown += entries
            print(f"{layout}: {figures['active']} active; mesh facts {figures['mesh_facts']}, absolute sizes "
                  f"{figures['absolute_sizes']}; name colours kept {figures['name_colour_share']} of "
                  f"{figures['name_colours']}, compounds kept {figures['compound_share']} of {figures['compounds']}, "
                  f"head noun kept {figures['noun_share']}; excluded by a caption collision "
                  f"{figures['excluded_by_collision']} (told apart {figures['told_apart']}); textured objects whose "
                  f"caption colour agrees with the render's dominant colour {figures['textured_agree']} of "
                  f"{figures['textured']} (lit side; {figures['textured_agree_all_pixels']} over every pixel); "
                  f"{figures['seconds']} s", file=sys.stderr)
            for line in figures["disagree"]:
                print(f"  disagrees: {line}", file=sys.stderr)
            for kind, lines in figures["misses"].items():
                for line in lines:
                    print(f"  {kind}: {line}", file=sys.stderr)
            print(json.dumps({k: v for k, v in figures.items() if k != "misses"}), flush=True)
        if args.sheet is not None:
            names = draw_sheet(shown, args.sheet, n=args.sheet_n, seed=args.seed)
            print(f"sheet {args.sheet}: {', '.join(names)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
