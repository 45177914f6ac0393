"""Untextured models look like what they are (issue 56 item 5): a model part with no texture, no vertex
colours and no material gets a ``[palette]`` look - from a metadata entry, a category word or a default
plastic picked by content hash - in the USD asset composed scenes render, and the captions name the
colour it renders with. No bpy here: tests/test_palette_render.py renders.

Real inputs: STLs of Debian's ``prusa-slicer`` and PyPI's ``metaworld`` (tests/public_packages.py; skipped
with the reason when they cannot be had), beside files the tests write."""

from __future__ import annotations

import colorsys
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from public_packages import cad_part_folders

from mixcount.captions.base import CaptionInput
from mixcount.captions.colours import NAMES, colours_from_model, family, name_rgb
from mixcount.captions.stub import StubCaptioner
from mixcount.catalog.materials import NAME_RGB, object_look, srgb_to_linear
from mixcount.config import load_config
from mixcount.errors import ConfigError
from mixcount.usd.assets import convert_asset

PALETTE = load_config().palette


def _look(metadata=None, name="part", category="part", content_hash="ab" * 32):
    return object_look(PALETTE, name=name, category=category, content_hash=content_hash,
                       metadata_json=None if metadata is None else json.dumps(metadata))


def test_look_from_metadata_category_and_default():
    steel = _look({"material": "steel"})
    assert steel.name == "steel" and steel.metallic == 1.0 and steel.source == "metadata"
    assert _look({"metadata": {"material": "Stainless Steel"}}).name == "steel"  # nested record, other words
    assert _look({"colour": "red"}).name == "red plastic"  # a colour name the palette has a plastic of
    magenta = _look({"color": "#D020C0"})
    assert magenta.rgb8() == (208, 32, 192) and magenta.source == "metadata"
    assert _look({"colour": [0.1, 0.2, 0.9]}).rgb8() == (26, 51, 230)
    assert name_rgb(_look({"colour": "navy"}).rgb8()) == "navy"  # a colour name no look has: its sRGB
    assert _look({"material": "unobtainium"}).source == "default"  # names nothing: the rules below it
    nut = _look(name="M3 hex nuts", category="shapes")
    assert (nut.name, nut.source) == ("brass", "category nut")  # a plural word of the name
    assert _look(category="screw").name == "steel"
    picks = {_look(content_hash=f"{k:064x}").name for k in range(40)}
    assert picks == set(PALETTE.default), picks  # the default plastics, spread by content hash
    assert _look(content_hash="12" * 32) == _look(content_hash="12" * 32)


def test_default_looks_stand_out_from_white_and_floors():
    """No default look is near-white, grey or a floor's beige / brown: each is saturated and mid-dark."""
    looks = {str(entry["name"]).lower(): entry for entry in PALETTE.looks}
    for name in PALETTE.default:
        rgb = np.asarray([int(str(looks[name.lower()]["colour"])[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
        _h, s, v = colorsys.rgb_to_hsv(*rgb)
        assert s >= 0.6 and v <= 0.96, (name, s, v)
        assert family(name_rgb(tuple(int(c * 255) for c in rgb))) not in ("white", "grey", "beige", "brown"), name


def test_name_rgb_table_names_itself_back():
    for name in NAMES:
        assert name_rgb(NAME_RGB[name]) == name, (name, NAME_RGB[name], name_rgb(NAME_RGB[name]))


@pytest.mark.parametrize("bad, says", [
    ({"palette.looks": [{"name": "x", "colour": "red", "metallic": 0.0, "roughness": 0.5}],
      "palette.default": ["x"], "palette.categories": []}, "#rrggbb"),
    ({"palette.default": ["chrome"]}, "not in palette.looks"),
    ({"palette.categories": ["nut"]}, "'word=look'"),
])
def test_palette_config_errors_say_what_is_wrong(bad, says):
    with pytest.raises(ConfigError, match=says):
        load_config(values=bad)


def _diffuse(asset: Path) -> list:
    """Every bound material's diffuseColor (a value) in the asset, in mesh order."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(asset))
    out = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or UsdGeom.Imageable(prim).GetPurposeAttr().Get() == "guide":
            continue
        mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not mat:
            out.append(None)
            continue
        surf = UsdShade.Shader(stage.GetPrimAtPath(mat.GetPath().AppendChild("PreviewSurface")))
        inp = surf.GetInput("diffuseColor")
        out.append(None if inp.HasConnectedSource() else tuple(inp.Get()))
    return out


def test_usd_asset_of_an_uncoloured_part_gets_its_look_and_coloured_parts_keep_theirs(tmp_path):
    stl = tmp_path / "nut.stl"
    trimesh.creation.cylinder(radius=3.0, height=2.0, sections=6).export(stl)
    ply = tmp_path / "painted.ply"
    painted = trimesh.creation.box(extents=(1, 1, 1))
    painted.visual = trimesh.visual.ColorVisuals(painted, vertex_colors=np.tile([40, 190, 70, 255], (8, 1)))
    painted.export(ply)
    brass = _look(category="nut").as_tuple()
    assert _diffuse(convert_asset(stl, tmp_path / "plain", content_hash="n0").visual) == [None]  # no look: as before
    asset = convert_asset(stl, tmp_path / "a", content_hash="n1", look=brass).visual
    np.testing.assert_allclose(_diffuse(asset)[0], srgb_to_linear(brass[:3]), atol=1e-5)
    assert _diffuse(convert_asset(ply, tmp_path / "a", content_hash="p1", look=brass).visual) == [None]  # its colours
    blue = _look({"colour": "blue"}).as_tuple()
    again = convert_asset(stl, tmp_path / "a", content_hash="n1", look=blue).visual  # a changed look: converted again
    np.testing.assert_allclose(_diffuse(again)[0], srgb_to_linear(blue[:3]), atol=1e-5)


def _real_parts() -> list[Path]:
    shapes, meshes = cad_part_folders()
    return [shapes / "M3_hex_nut.stl", shapes / "PLA_recycling_symbol.stl", meshes / "puck" / "puck.stl",
            meshes / "thermos" / "therm_body.stl"]


def test_real_cad_parts_are_captioned_in_the_colour_their_asset_renders_with(tmp_path):
    captioner = StubCaptioner("test")
    said = {}
    for k, model in enumerate(_real_parts()):
        look = object_look(PALETTE, name=model.stem, category=model.parent.name, metadata_json=None,
                           content_hash=f"{k:064x}")
        colours = colours_from_model(model, look=look.as_tuple())
        assert colours.names == (name_rgb(look.rgb8()),), (model.name, colours, look)
        assert colours_from_model(model).names == ()  # without a look: nothing to name (it renders grey)
        np.testing.assert_allclose(
            _diffuse(convert_asset(model, tmp_path / "assets", content_hash=f"{k:064x}", units="mm",
                                   look=look.as_tuple()).visual)[0], srgb_to_linear(look.rgb), atol=1e-5)
        item = CaptionInput(object_id=k, name=model.stem, category=model.parent.name, dims=(0.05, 0.05, 0.02),
                            colours=colours)
        said[model.name] = captioner.caption(item).short
        assert name_rgb(look.rgb8()) in said[model.name].split(), said
    print(said)
