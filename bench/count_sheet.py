"""A contact sheet of count-target scenes beside paper scenes of the same counts (issue 48's docs PNG).

    .venv/bin/python bench/count_sheet.py --paper W/out_paper --target W/out_histogram_... \
        --dense W2/out_uniform_1000-1000 --pairs 6 --out docs/count_targets_look.png

Every ``scenes/scene_*`` folder under ``--paper`` and ``--target`` (bench/counts.py's per-seed folders) is
read; target and paper scenes are paired by the nearest kept counts (the closest pairs first, each scene
once), ``--pairs`` pairs in all. Each tile is the
scene's rgb.png (``--tile`` px, 512 by default) captioned with its seed, kept count, counted image share,
union box and counted pixels' luminance (bench/counts.py :func:`scene_look`); the ``--dense`` scene(s) come
last. stdout: one JSON line naming the pairs and their figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))


def scenes(root: Path) -> list[dict[str, Any]]:
    from counts import scene_look

    out = []
    for meta_path in sorted(root.glob("**/scenes/scene_*/metadata.json")):
        meta = json.loads(meta_path.read_text())
        out.append({"dir": meta_path.parent, "seed": meta.get("seed"), "kept": int(meta["n_counted"]),
                    **scene_look(meta_path.parent, meta)})
    return out


def pairs(paper: list[dict[str, Any]], target: list[dict[str, Any]], n: int) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Up to ``n`` (paper, target) pairs of the nearest counts, each scene used once: the closest pairs
    first over all of them, then in order of the count."""
    cands = sorted(((abs(p["kept"] - t["kept"]), i, j) for i, p in enumerate(paper) for j, t in enumerate(target)))
    used_p: set[int] = set()
    used_t: set[int] = set()
    out = []
    for _, i, j in cands:
        if i in used_p or j in used_t or len(out) >= n:
            continue
        used_p.add(i)
        used_t.add(j)
        out.append((paper[i], target[j]))
    return sorted(out, key=lambda pt: pt[1]["kept"])


def tile(rec: dict[str, Any], label: str, side: int) -> Any:
    from PIL import Image, ImageDraw

    img = Image.open(rec["dir"] / "rgb.png").convert("RGB").resize((side, side), Image.LANCZOS)
    canvas = Image.new("RGB", (side, side + 34), "white")
    canvas.paste(img, (0, 34))
    d = ImageDraw.Draw(canvas)
    d.text((4, 2), f"{label} seed {rec['seed']}: {rec['kept']} counted", fill="black")
    d.text((4, 17), f"share {rec['image_share']:.3f}  box {rec.get('union_box', 0):.2f}  "
                    f"lum {rec.get('luminance', 0):.2f}", fill="black")
    return canvas


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paper", type=Path, required=True)
    ap.add_argument("--target", type=Path, required=True)
    ap.add_argument("--dense", type=Path, default=None)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--tile", type=int, default=512)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    from PIL import Image

    chosen = pairs(scenes(args.paper), scenes(args.target), args.pairs)
    dense = scenes(args.dense) if args.dense else []
    cols = 2 + (1 if dense else 0)
    h = args.tile + 34
    sheet = Image.new("RGB", (cols * args.tile + (cols - 1) * 8, len(chosen) * h + (len(chosen) - 1) * 8), "white")
    for r, (p, t) in enumerate(chosen):
        sheet.paste(tile(p, "paper", args.tile), (0, r * (h + 8)))
        sheet.paste(tile(t, "target", args.tile), (args.tile + 8, r * (h + 8)))
    for r, d in enumerate(dense[: len(chosen)]):
        sheet.paste(tile(d, "target", args.tile), (2 * (args.tile + 8), r * (h + 8)))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet.quantize(256, dither=Image.Dither.FLOYDSTEINBERG).save(args.out, optimize=True)  # a docs-sized PNG
    keep = ("seed", "kept", "image_share", "union_box", "luminance", "visible_px_median")
    print(json.dumps({"bench": "count_sheet", "out": str(args.out),
                      "pairs": [{"paper": {k: p.get(k) for k in keep}, "target": {k: t.get(k) for k in keep}}
                                for p, t in chosen], "dense": [{k: d.get(k) for k in keep} for d in dense]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
