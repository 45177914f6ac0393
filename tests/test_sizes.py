"""mixcount.sizes: the size prior and the unit ratios both ingest and curation read."""

import pytest

from mixcount.sizes import plausible_unit, size_ratio_evidence, unit_explained_ratio


@pytest.mark.parametrize("side, assumed, expected", [
    (6.35, "m", "mm"),      # a 6.35 mm hex nut read as metres
    (193.0, "m", "mm"),     # a 193 mm spider
    (0.12, "m", None),      # a mug in metres: plausible, kept
    (12.0, "cm", None),     # 12 cm: plausible
    (0.0001, "m", None),    # 0.1 mm is implausible in every unit: nothing to re-read it in
])
def test_plausible_unit_rereads_only_implausible_sizes(side, assumed, expected):
    assert plausible_unit(side, assumed) == expected


def test_unit_ratios_and_rescales_are_told_apart_from_real_size_differences():
    assert unit_explained_ratio(1000.0) == "m/mm"
    assert unit_explained_ratio(1 / 25.4) == "in/mm"
    assert unit_explained_ratio(15.75) is None
    assert not size_ratio_evidence(0.10, 0.125).against          # a 25 % squash
    assert not size_ratio_evidence(0.1, 0.1 * 25.4).against      # inches read as mm
    ev = size_ratio_evidence(0.0063, 0.0993)                      # a hex nut against a hockey puck
    assert ev.against and "more than" in ev.describe()
