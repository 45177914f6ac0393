"""The readers behind real folders (issue 52): which file names are companions, what a URDF/SDF says."""

from __future__ import annotations

import pytest

from mixcount.catalog.layouts.companions import companion_base, companion_kind, read_description, up_axis_of_rpy
from mixcount.frame import unit_scale


@pytest.mark.parametrize("stem, kind", [
    ("mug_col", "collision"), ("duck_vhacd", "collision"), ("teddy2_VHACD_CHs", "collision"),
    ("l_finger_collision", "collision"), ("boat-hull", "collision"), ("chair_lod1", "lod"), ("Chair_LOD2", "lod"),
    ("mug", None), ("chair_lod0", None), ("hull", None), ("protocol", None), ("coffee_mug_02", None),
])
def test_companion_names(stem, kind):
    assert companion_kind(stem) == kind


def test_companion_base():
    assert companion_base("mug_col") == "mug" and companion_base("duck_vhacd") == "duck"
    assert companion_base("chair_lod1") == "chair"


@pytest.mark.parametrize("rpy, up", [((0, 0, 0), "Z"), ((1.5707963, 0, 0), "Y"), ((0, 0, 1.5708), "Z"),
                                     ((0, -1.5707963, 0), "X"), ((3.14159, 0, 0), None), ((0.5, 0, 0), None)])
def test_up_axis_of_a_visual_rotation(rpy, up):
    assert up_axis_of_rpy(rpy) == up


def test_urdf_and_sdf_are_read(tmp_path):
    urdf = tmp_path / "duck.urdf"
    urdf.write_text('<robot name="duck.urdf"><link name="b"><visual><origin rpy="1.5707963 0 0"/><geometry>'
                    '<mesh filename="package://ducks/meshes/duck.obj" scale=".05 .05 .05"/></geometry></visual>'
                    '<collision><geometry><mesh filename="duck_vhacd.obj"/></geometry></collision></link></robot>')
    d = read_description(urdf)
    assert d is not None
    assert (d.name, d.visual, d.collision, d.up_axis, d.units()) == ("duck", "duck.obj", "duck_vhacd.obj", "Y", "0.05")
    sdf = tmp_path / "m.sdf"
    sdf.write_text('<sdf><model name="ball"><link name="l"><visual name="v"><pose>0 0 0 0 0 0</pose><geometry>'
                   '<mesh><uri>model://ball/ball.obj</uri><scale>0.1 0.1 0.2</scale></mesh></geometry></visual>'
                   '</link></model></sdf>')
    d = read_description(sdf)
    assert d is not None and (d.name, d.visual, d.up_axis) == ("ball", "ball.obj", "Z")
    assert d.units() is None and "unevenly" in d.warnings[0]  # an uneven scale is reported, not applied
    (tmp_path / "bad.urdf").write_text("<robot")
    assert read_description(tmp_path / "bad.urdf") is None


def test_units_as_a_number():
    assert unit_scale("cm") == 0.01 and unit_scale("0.05") == 0.05
    for bad in ("furlong", "-1", "0", "inf", "nan"):
        with pytest.raises(ValueError, match="unknown units"):
            unit_scale(bad)
