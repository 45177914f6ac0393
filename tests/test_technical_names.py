"""Categories of technical names (issue 70 item 6): the noun a person would use, not a pin count's unit or a
package ("DIP-8 IC NE555" -> ic, "Screw terminal 2 pin" -> terminal block).

The rule (:func:`mixcount.catalog.naming.technical_category`) was written against the issue's names and a
few of KiCad's library file names; it is checked here on two sources it was not written against: the 3D
model names the PCBs of Debian's ``kicad-demos`` use (their library folder says what each is), and the part
classes of PyPI's ``bd_warehouse`` (nuts, screws, washers, bearings: none may change category)."""

from __future__ import annotations

import re

import pytest
from public_packages import deb_tree, wheel_tree

from mixcount.catalog.naming import category_from_name, category_from_stem, technical_category


@pytest.mark.parametrize(("name", "category"), [
    ("DIP-8 IC NE555", "ic"),
    ("Screw terminal 2 pin", "terminal block"),
    ("LED 5mm red", "led"),
    ("Electrolytic capacitor 100uF", "capacitor"),
    ("Hex nut M6 (STEP)", "nut"),  # not technical: the plain rule
    ("Socket wrench 10mm", "wrench"),  # an everyday word of the table, in a plain name
    ("Red Ceramic Mug", "mug"),
    ("Bowling pin", "pin"),
])
def test_person_names(name, category):
    assert category_from_name(name) == category


def test_library_file_names():
    assert category_from_stem("CP_Radial_D5.0mm_P2.00mm", "models") == "capacitor"
    assert category_from_stem("PinHeader_1x04_P2.54mm_Vertical", "models") == "pin header"
    assert category_from_stem("mug_02", "models") == "mug" and technical_category("coffee-mug-02") is None


FAMILY = {"Resistor": {"resistor"}, "Capacitor": {"capacitor"}, "Diode": {"diode"}, "LED": {"led"},
          "Package_DIP": {"ic", "socket"}, "Package_SO": {"ic"}, "Package_QFP": {"ic"},
          "Package_TO_SOT": {"transistor", "ic", "regulator"}, "TerminalBlock": {"terminal block"},
          "Connector": {"connector", "pin header", "pin socket", "terminal block", "jack", "barrel jack"},
          "Crystal": {"crystal", "oscillator"}, "Potentiometer": {"potentiometer"}, "Button_Switch": {"switch", "button"}}


def test_kicad_demo_model_names_get_their_library_kind():
    """Each 3D model a kicad-demos PCB names (``Capacitor_SMD.3dshapes/C_0805_2012Metric.wrl``): its file name
    gets the kind its library folder says (a DIP footprint "with socket" may say socket). At the time of
    writing 76 of 85; the plain rule alone got 7 (it took "metric", "horizontal", "mm")."""
    root, why = deb_tree("kicad-demos")
    if root is None:
        pytest.skip(why)
    found: set[tuple[str, str]] = set()
    for pcb in (root / "usr/share/kicad/demos").rglob("*.kicad_pcb"):
        found |= set(re.findall(r"([A-Za-z_]+)\.3dshapes/([^\"/]+?)\.(?:wrl|step|stp)", pcb.read_text(errors="replace")))
    judged = [(stem, fam) for lib, stem in found
              for fam in [next((v for k, v in FAMILY.items() if lib.startswith(k)), None)] if fam is not None]
    right = [stem for stem, fam in judged if category_from_stem(stem, "3dshapes") in fam]
    assert len(judged) >= 60 and len(right) >= 0.8 * len(judged), (len(right), len(judged))


def test_bd_warehouse_parts_keep_their_plain_nouns():
    root, why = wheel_tree("bd_warehouse==0.4.0")
    if root is None:
        pytest.skip(why)
    classes = sorted({c for f in (root / "bd_warehouse").glob("*.py")
                      for c in re.findall(r"^class (\w+)", f.read_text(), re.M)})
    assert len(classes) > 60
    changed = []
    for cls in classes:
        words = " ".join(re.findall(r"[A-Z]+(?![a-z])|[A-Z][a-z]+", cls))
        for name in (f"{words} M6 iso4032", f"{cls}_M8-1.25_iso4032"):
            tech = technical_category(name)
            if tech is not None and tech != category_from_name(words.split()[-1]):
                changed.append((name, tech))
    assert not changed, changed  # "Button Head Screw" stays a screw, "Socket Weld Flange" a flange


def test_pin_counts_of_technical_names_only():
    from mixcount.catalog.naming import pin_count

    assert pin_count("PhoenixContact_MC_1,5_3-G-3.81_1x03_P3.81mm_Horizontal") == 3
    assert pin_count("IDC-Header_2x05_P2.54mm_Vertical") == 10 and pin_count("Screw terminal 2 pin") == 2
    assert pin_count("DIP-8 IC NE555") == 8
    assert pin_count("BatteryHolder_Keystone_1058_1x2032") is None  # a CR2032 cell, not 2032 pins
    assert pin_count("DSUB-9_Male_Horizontal_P2.77x2.54mm") is None  # a pitch, not a grid
    assert pin_count("Box 10x20") is None  # not a technical name
