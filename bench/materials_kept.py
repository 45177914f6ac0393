"""Materials in a model file against those in its converted USD asset, per source kind (issue 70 item 1).

    .venv/bin/python bench/materials_kept.py FILE_OR_FOLDER ...        # STEP, OBJ, glTF/GLB, USD files
    .venv/bin/python bench/materials_kept.py --parts A.step B.glb      # also: the files merged as one object's parts

For each file: ``in file`` = the distinct looks its materials give (STEP: distinct ``COLOUR_RGB`` values;
OBJ: the distinct Kd / map_Kd of the materials its faces use; glTF: the distinct base colour factor /
texture of the materials its primitives use; USD: the distinct looks of the materials bound to its meshes), and
``in asset`` = the distinct looks bound to the meshes of the converted asset (a constant diffuse colour,
a texture's pixels, or vertex colours), converted as compose converts it: STEP and part folders through
the derived GLB (:mod:`mixcount.catalog.derived`), then :func:`mixcount.usd.assets.convert_asset`.
One row per file on stdout (tab-separated), the totals per kind last.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import struct
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

KINDS = {".step": "STEP", ".stp": "STEP", ".obj": "OBJ", ".glb": "glTF", ".gltf": "glTF", ".usd": "USD",
         ".usda": "USD", ".usdc": "USD", ".usdz": "USD"}
_COLOUR = re.compile(r"COLOUR_RGB\s*\(\s*'[^']*'\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)", re.I)


def step_colours(path: Path) -> set[tuple[float, ...]]:
    text = path.read_text(errors="replace")
    return {tuple(round(float(v), 3) for v in m) for m in _COLOUR.findall(text)}


def step_looks(path: Path) -> int:
    return len(step_colours(path))


def obj_looks(path: Path) -> int:
    used: set[str] = set()
    libs: list[Path] = []
    for line in path.read_text(errors="replace").splitlines():
        if line.startswith("usemtl "):
            used.add(line[7:].strip())
        elif line.startswith("mtllib "):
            libs.append(path.parent / line[7:].strip())
    defs: dict[str, dict[str, str]] = {}
    for lib in libs:
        current = None
        for line in lib.read_text(errors="replace").splitlines() if lib.is_file() else ():
            word, _, rest = line.strip().partition(" ")
            if word == "newmtl":
                current = rest.strip()
                defs[current] = {}
            elif current is not None and word in ("Kd", "map_Kd"):
                defs[current][word] = rest.strip()
    return len({json.dumps(defs.get(name, {}), sort_keys=True) for name in used})


def gltf_looks(path: Path) -> int:
    if path.suffix.lower() == ".glb":
        data = path.read_bytes()
        doc = json.loads(data[20:20 + struct.unpack_from("<I", data, 12)[0]])
    else:
        doc = json.loads(path.read_text())
    mats = doc.get("materials", [])
    used = {p.get("material") for m in doc.get("meshes", []) for p in m.get("primitives", [])}
    looks = set()
    for k in used:
        pbr = mats[k].get("pbrMetallicRoughness", {}) if k is not None and k < len(mats) else {}
        looks.add(json.dumps([pbr.get("baseColorFactor"), (pbr.get("baseColorTexture") or {}).get("index")]))
    return len(looks)


def usd_looks(path: Path) -> int:
    return asset_looks(path)  # the distinct looks bound to its meshes, counted as in an asset


def file_looks(path: Path) -> int:
    kind = KINDS[path.suffix.lower()]
    return {"STEP": step_looks, "OBJ": obj_looks, "glTF": gltf_looks, "USD": usd_looks}[kind](path)


def asset_looks(asset: Path) -> int:
    """Distinct looks bound to the visual meshes of a converted asset."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(asset))
    looks = set()
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.guide:
            continue
        mat, _rel = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not mat:
            dc = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
            looks.add("displayColor:" + (str(sorted({tuple(round(float(x), 3) for x in c) for c in dc.Get()}))
                                         if dc and dc.HasValue() else "none"))
            continue
        looks.add(_material_look(mat, prim))
    return len(looks)


def _material_look(mat, mesh_prim) -> str:  # type: ignore[no-untyped-def]
    from pxr import Sdf, UsdGeom, UsdShade

    surface = mat.ComputeSurfaceSource()[0]
    if not surface:
        return f"material:{mat.GetPath()}"
    diffuse = surface.GetInput("diffuseColor")
    if diffuse is None:
        return f"material:{mat.GetPath()}"
    if diffuse.HasConnectedSource():
        src = diffuse.GetConnectedSource()[0]
        shader = UsdShade.Shader(src.GetPrim())
        if shader.GetIdAttr().Get() == "UsdUVTexture":
            file = shader.GetInput("file").Get()
            resolved = file.resolvedPath if isinstance(file, Sdf.AssetPath) else ""
            digest = hashlib.sha256(Path(resolved).read_bytes()).hexdigest()[:16] if resolved else str(file)
            return f"texture:{digest}"
        dc = UsdGeom.PrimvarsAPI(mesh_prim).GetPrimvar("displayColor")
        values = dc.Get() if dc and dc.HasValue() else []
        return "vertex:" + str(sorted({tuple(round(float(x), 2) for x in c) for c in values})[:8])
    value = diffuse.Get()
    return "constant:" + str(tuple(round(float(x), 3) for x in value)) if value is not None else "constant:none"


def convert(sources: list[Path], work: Path, key: str) -> Path:
    from mixcount.catalog.derived import build_glb
    from mixcount.frame import STEP_EXTENSIONS
    from mixcount.usd.assets import convert_asset

    model = sources[0]
    units, up = "m", "Y"
    if len(sources) > 1 or model.suffix.lower() in STEP_EXTENSIONS:
        model = work / f"{key}.glb"
        build_glb([(p, None) for p in sources], model)
        up = "Z" if model.suffix.lower() in STEP_EXTENSIONS or sources[0].suffix.lower() in STEP_EXTENSIONS else "Y"
    return convert_asset(model, work / "usd", content_hash=key, units=units, up_axis=up,
                         look=(0.5, 0.5, 0.5, 0.0, 0.5)).visual


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="*", type=Path)
    parser.add_argument("--parts", nargs="+", type=Path, default=[], help="files merged as one object's parts")
    parser.add_argument("--smoke", action="store_true",
                        help="the smoke run of tests/test_benches.py: two coloured STEP parts of Debian's kicad-demos")
    args = parser.parse_args(argv)
    if args.smoke:
        found, why = smoke_inputs()
        if found is None:
            print(json.dumps({"skipped": why}))
            return 0
        args.paths = found
    files: list[Path] = []
    for p in args.paths:
        files.extend(sorted(f for f in p.rglob("*") if f.suffix.lower() in KINDS) if p.is_dir() else [p])
    work = Path(tempfile.mkdtemp(prefix="materials_kept_"))
    totals: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0])  # files, kept all, looks in files, in assets
    print("kind\tfile\tin file\tin asset")
    rows = [(KINDS[f.suffix.lower()], [f]) for f in files]
    if args.parts:
        rows.append(("parts", args.parts))
    for k, (kind, sources) in enumerate(rows):
        if kind == "parts":  # colours shared by two STEP parts are one look
            steps = [s for s in sources if KINDS[s.suffix.lower()] == "STEP"]
            want = len(set().union(*(step_colours(s) for s in steps))) + sum(file_looks(s) for s in sources
                                                                            if s not in steps)
        else:
            want = file_looks(sources[0])
        try:
            got = asset_looks(convert(sources, work, f"m{k:03d}"))
        except Exception as exc:  # a file the converter refuses: said, counted as nothing kept
            print(f"{kind}\t{'+'.join(s.name for s in sources)}\t{want}\terror: {exc}"[:300])
            got = 0
        else:
            print(f"{kind}\t{'+'.join(s.name for s in sources)}\t{want}\t{got}")
        t = totals[kind]
        t[0] += 1
        t[1] += int(got >= want)
        t[2] += want
        t[3] += got
    for kind, (n, kept, want, got) in sorted(totals.items()):
        print(f"# {kind}: {n} files, all looks kept in {kept}; looks in files {want}, in assets {got}")
    print(json.dumps({kind: {"files": n, "kept_all": kept, "looks_in_files": want, "looks_in_assets": got}
                      for kind, (n, kept, want, got) in sorted(totals.items())}))
    return 0


SMOKE_PARTS = ("APHB1608.step", "Crystal_SMD_4P_2520.step")  # an LED and a crystal: 2-4 colours each


def smoke_inputs() -> tuple[list[Path] | None, str]:
    """The smoke run's STEP files (fetched and cached by tests/public_packages.py), or None and why not."""
    sys.path.insert(0, str(ROOT / "tests"))
    from public_packages import deb_tree  # type: ignore[import-not-found]

    root, why = deb_tree("kicad-demos")
    if root is None:
        return None, why
    folder = root / "usr/share/kicad/demos/stickhub/3dmodels"
    return [folder / name for name in SMOKE_PARTS], ""


if __name__ == "__main__":
    raise SystemExit(main())
