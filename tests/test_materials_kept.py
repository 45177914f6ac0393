"""Every material of a model kept (issue 70 item 1): STEP parts of several colours, OBJ and glTF of several
materials, converted as compose converts them (STEP through the derived GLB), keep each colour in the USD
asset; a multi-colour STEP part renders (real bpy, 32 px) in more than one colour and its caption names
colours it shows.

Real inputs: the coloured STEP models of Debian's ``kicad-demos`` (the stickhub demo's LED, crystal, JST
connector and TDFN-8 IC: not the files the rule was written against, which were KiCad library models of
``kicad-packages3d``, docs/usd.md), OBJ and glTF test models of ``assimp-testmodels``."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from public_packages import ASSIMP_MODELS, deb_tree

from mixcount.catalog.derived import build_glb
from mixcount.catalog.units import shown_unit, step_length_unit
from mixcount.usd.assets import convert_asset

STICKHUB = "usr/share/kicad/demos/stickhub/3dmodels"
_COLOUR = re.compile(r"COLOUR_RGB\s*\(\s*'[^']*'\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)\s*,\s*([-\d.Ee+]+)", re.I)


@pytest.fixture(scope="module")
def stickhub() -> Path:
    root, why = deb_tree("kicad-demos")
    if root is None:
        pytest.skip(why)
    return root / STICKHUB


def _file_colours(step: Path) -> set[tuple[float, ...]]:
    return {tuple(round(float(v), 3) for v in m) for m in _COLOUR.findall(step.read_text(errors="replace"))}


def _asset_colours(asset: Path) -> list[tuple[float, ...]]:
    """The constant diffuse colour of every material bound to a visual mesh of the asset."""
    from pxr import Usd, UsdGeom, UsdShade

    out = []
    stage = Usd.Stage.Open(str(asset))  # held: a prim range outlives no stage
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.guide:
            continue
        mat, _rel = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        assert mat, f"{prim.GetPath()} has no material"
        value = mat.ComputeSurfaceSource()[0].GetInput("diffuseColor").Get()
        out.append(tuple(round(float(v), 3) for v in value))
    return out


def _surface_colours(step: Path) -> list[tuple[float, ...]]:
    """The colours OpenCASCADE finds on the part's surfaces (cascadio's glTF materials, linear RGB): a
    colour of the file that styles only a solid whose every face has its own is on no surface."""
    import json
    import struct

    import cascadio

    glb = cascadio.load(step.read_bytes(), file_type="step", merge_primitives=True)
    doc = json.loads(glb[20:20 + struct.unpack_from("<I", glb, 12)[0]])
    return [tuple(m["pbrMetallicRoughness"]["baseColorFactor"][:3]) for m in doc["materials"]]


def test_every_colour_of_a_step_part_is_in_its_usd_asset(stickhub, tmp_path):
    from mixcount.catalog.materials import srgb_to_linear

    steps = sorted(p for p in stickhub.iterdir() if p.suffix.lower() in (".step", ".stp"))
    assert len(steps) == 4
    for k, step in enumerate(steps):
        glb = tmp_path / f"{step.stem}.glb"
        build_glb([(step, None)], glb)
        asset = convert_asset(glb, tmp_path / "usd", content_hash=f"s{k}", units="m", up_axis="Z",
                              look=(0.5, 0.5, 0.5, 0.0, 0.5)).visual
        colours = set(_asset_colours(asset))
        surfaces = _surface_colours(step)
        assert len(surfaces) >= 2 and len(colours) == len(surfaces), (step.name, surfaces, colours)
        in_file = np.array([srgb_to_linear(c) for c in _file_colours(step)])  # the file's sRGB, linear
        for c in colours:  # each is one of the file's own colours (within 8-bit rounding)
            assert np.abs(in_file - np.asarray(c)).max(axis=1).min() < 0.01, (step.name, c)
        assert step_length_unit(step) == "mm"  # drawn in millimetres, read into metres


def test_parts_merged_keep_the_colours_of_every_part(stickhub, tmp_path):
    led, ic = stickhub / "APHB1608.step", stickhub / "TDFN-8_1.5x2mm_Fused-Lead_MO-252-W2015D.step"
    glb = tmp_path / "merged.glb"
    beside = np.eye(4)
    beside[0, 3] = 0.004  # the IC 4 mm beside the LED, as a description's placement puts a part
    build_glb([(led, None), (ic, beside)], glb)
    asset = convert_asset(glb, tmp_path / "usd", content_hash="merged", units="m", up_axis="Z").visual
    assert set(_asset_colours(asset)) >= set(_asset_colours(_single(led, tmp_path))) | set(
        _asset_colours(_single(ic, tmp_path)))


def _single(step: Path, tmp_path: Path) -> Path:
    glb = tmp_path / f"one_{step.stem}.glb"
    build_glb([(step, None)], glb)
    return convert_asset(glb, tmp_path / "usd", content_hash=f"one_{step.stem}", units="m", up_axis="Z").visual


@pytest.mark.parametrize(("relpath", "looks"), [
    ("OBJ/cube_usemtl.obj", 2),  # two materials of one Kd, and a third the .mtl lacks (the palette look)
    ("OBJ/regr01.obj", 11),  # 11 materials used, of 10 distinct Kd, and one the .mtl lacks (the palette look)
    ("glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb", 7),  # 7 distinct base colours on 34 meshes
])
def test_obj_and_gltf_of_several_materials_keep_them(relpath, looks, tmp_path):
    root, why = deb_tree("assimp-testmodels")
    if root is None:
        pytest.skip(why)
    model = tmp_path / Path(relpath).name
    src = root / ASSIMP_MODELS / relpath
    for f in src.parent.iterdir():
        shutil.copy(f, tmp_path / f.name)
    asset = convert_asset(model, tmp_path / "usd", content_hash="m", units="m", up_axis="Y",
                          look=(0.5, 0.5, 0.5, 0.0, 0.5)).visual
    from pxr import Usd, UsdShade

    stage = Usd.Stage.Open(str(asset))
    unbound = [p for p in stage.Traverse() if p.GetTypeName() == "Mesh"
               and not UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()[0]]
    assert not unbound and len(set(_asset_colours(asset))) == looks


def test_unit_shown_is_the_steps_own():
    reason = "format: the STEP file states mm (read into metres by OpenCASCADE)"
    assert shown_unit("m", reason) == "mm" and shown_unit("cm", "stated: --units cm") == "cm"


@pytest.mark.blender
@pytest.mark.slow
def test_a_multi_colour_part_renders_and_is_captioned_in_its_colours(stickhub, tmp_path, capsys):
    """The LED (white lens, orange and yellow dies, a dark base, a green mark) ingested from its STEP, rendered
    at 32 px: its pixels hold more than one colour name, and the caption's colours are among them."""
    import json

    from PIL import Image
    from sqlalchemy import select

    from mixcount.captions.colours import colour_words_in, family, name_rgb
    from mixcount.catalog.db import open_catalog
    from mixcount.catalog.models import CaptionSet, CatalogObject
    from mixcount.cli import main
    from mixcount.curation.renders import canonical_render_path, mask_path_for

    lib = tmp_path / "lib"
    for folder, name in (("Crystal 2520", "Crystal_SMD_4P_2520.step"), ("JST SH connector", "JST_SH_SM04B-SRSS-TB.STEP")):
        (lib / folder).mkdir(parents=True)
        shutil.copy(stickhub / name, lib / folder / name)
    db = str(tmp_path / "catalog.db")
    small = ["--db", db, "--config", "quick", "--set", "canonical_render.resolution=48",
             "--set", "canonical_render.samples=2"]
    assert main([*small, "catalog", "ingest", str(lib), "--workers", "1"]) == 0
    assert main([*small, "catalog", "render"]) == 0
    assert main([*small, "catalog", "caption"]) == 0
    assert main([*small, "catalog", "list"]) == 0
    listed = capsys.readouterr().out
    assert "mm / " in listed, listed  # the STEP's own unit, not the metres OpenCASCADE read it into
    cat = open_catalog(db, data_dir="")
    try:
        with cat.session() as s:
            objs = list(s.scalars(select(CatalogObject)))
            renders = {o.name: canonical_render_path(s, o.id) for o in objs}
            short = {o.name: cs.short for o in objs
                     for cs in s.scalars(select(CaptionSet).where(CaptionSet.object_id == o.id,
                                                                  CaptionSet.active.is_(True)))}
            units = {o.name: json.loads(o.metadata_json)["ingest"]["units_reason"] for o in objs}
    finally:
        cat.close()
    assert len(renders) == 2, renders
    for name, path in renders.items():
        assert path is not None and "states mm" in units[name]
        rgb = np.asarray(Image.open(path).convert("RGB"))
        mask = np.asarray(Image.open(mask_path_for(path))) > 200
        names = [family(name_rgb(tuple(int(c) for c in px))) or name_rgb(tuple(int(c) for c in px)) for px in rgb[mask]]
        counts = {n: names.count(n) for n in set(names)}
        shown = {n for n, c in counts.items() if c >= 0.05 * mask.sum()}
        assert len(shown) >= 2, (name, counts)  # before issue 70: one colour, the first material's
        said = {family(w) or w for w in colour_words_in(short[name])}
        assert said and said <= shown | {"grey", "white", "black"} and said & shown, (name, short[name], counts)
