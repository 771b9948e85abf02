"""GRBL and board settings share one descriptor style (TypedSetting): same conversions,
same refusals, same messages; GRBL's read their values from the ``$$`` dump."""

from __future__ import annotations

import pytest

from hil.devices.board_settings import BoardSettings
from hil.devices.grbl_settings import GrblSettings
from hil.devices.setting_descriptor import TypedSetting
from hil.errors import ConfigError

DUMP = GrblSettings({20: "1", 22: "1", 24: "25.000", 25: "500.000", 26: "250", 27: "1.000",
                     110: "600.000", 130: "400.000", 131: "200.000"})  # fmt: skip


def test_both_devices_declare_settings_with_the_same_descriptor() -> None:
    assert isinstance(GrblSettings.max_rate_x, TypedSetting)
    assert isinstance(BoardSettings.sample_rate_hz, TypedSetting)
    assert GrblSettings.max_rate_x.label == "max_rate_x ($110)"
    assert BoardSettings.sample_rate_hz.label == "sample_rate_hz"


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("max_rate_x", True, r"max_rate_x \(\$110\) = True is not allowed: must be a number in "
         r"\(0, 1e\+06\] mm/min; give the X max rate in mm/min"),
        ("max_rate_x", "600", r"max_rate_x \(\$110\) = '600' is not allowed"),
        ("max_rate_x", float("nan"), r"max_rate_x \(\$110\) = nan is not allowed"),
        ("soft_limits", 2, r"soft_limits \(\$20\) = 2 is not allowed: must be a boolean "
         r"\(True/False or 0/1\); soft limits need homing"),
        ("homing_debounce", 2.5, r"homing_debounce \(\$26\) = 2.5 is not allowed: must be an "
         r"integer in \[0, 65535\] ms"),
    ],
)  # fmt: skip
def test_a_bad_grbl_value_is_refused_naming_the_setting(name: str, value: object,
                                                        message: str) -> None:  # fmt: skip
    with pytest.raises(ConfigError, match=message):
        DUMP.check(name, value)


def test_good_grbl_values_format_their_lines() -> None:
    assert DUMP.check("soft_limits", True) == "$20=1"
    assert DUMP.check("homing_enabled", 0) == "$22=0"
    assert DUMP.check("homing_debounce", 100.0) == "$26=100"
    assert DUMP.check("max_rate_x", 900) == "$110=900.000"


def test_board_refuses_a_bool_for_a_number_like_grbl_does() -> None:
    with pytest.raises(ConfigError, match=r"sample_rate_hz = True is not allowed: must be "
                       r"1 .. 100000000 Hz"):  # fmt: skip
        BoardSettings(sample_rate_hz=True)


def test_homing_time_bound_for_an_x_only_build_and_missing_axes() -> None:
    # X only: 1.5*400/500*60 + 2*1/500*60 + 5*1/25*60 + 4*0.25 = 72 + 0.24 + 12 + 1.
    assert DUMP.homing_time_bound(("X",)) == pytest.approx(85.24)
    # Stock cycles: Z has no travel in this dump (skipped); XY takes the longer, X.
    assert DUMP.homing_time_bound() == pytest.approx(85.24)
    assert DUMP.travel_mm("Y") == 200.0 and DUMP.travel_mm("Z") is None
