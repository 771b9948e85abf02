"""GRBL 1.1 line parsing and formatting, with exchanges from the interface documentation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.devices.grbl_codes import CRITICAL_ALARMS, alarm_recovery, alarm_text, error_text
from hil.devices.grbl_protocol import (
    AlarmMessage,
    Banner,
    ErrorResponse,
    Feedback,
    LineSplitter,
    Ok,
    SettingLine,
    StartupLine,
    StatusReport,
    Unrecognised,
    format_jog_line,
    format_move_line,
    format_number,
    parse_line,
)
from hil.devices.grbl_settings import GrblSettings
from hil.errors import ConfigError

# The ``$$`` print-out of the GRBL 1.1 interface documentation, verbatim.
DOC_SETTINGS_DUMP = """$0=10
$1=25
$2=0
$3=0
$4=0
$5=0
$6=0
$10=255
$11=0.010
$12=0.002
$13=0
$20=0
$21=0
$22=0
$23=0
$24=25.000
$25=500.000
$26=250
$27=1.000
$30=1000
$31=0
$32=0
$100=250.000
$101=250.000
$102=250.000
$110=500.000
$111=500.000
$112=500.000
$120=10.000
$121=10.000
$122=10.000
$130=200.000
$131=200.000
$132=200.000
ok
"""


def test_documented_status_report_with_buffer_and_pins() -> None:
    report = parse_line("<Idle|MPos:0.000,0.000,0.000|FS:0,0|Bf:15,128|Pn:XYZ>")
    assert isinstance(report, StatusReport)
    assert (report.state, report.substate, report.mpos) == ("Idle", None, (0.0, 0.0, 0.0))
    assert (report.feed, report.spindle) == (0.0, 0.0)
    assert (report.planner_blocks_free, report.rx_bytes_free) == (15, 128)
    assert report.pins == "XYZ"
    assert report.wpos is None and report.wco is None


def test_documented_wpos_and_wco_give_machine_position() -> None:
    report = parse_line("<Run|WPos:-2.500,0.000,11.000|WCO:0.000,1.551,5.664|FS:500,8000>")
    assert isinstance(report, StatusReport)
    assert report.wpos == (-2.5, 0.0, 11.0)
    assert report.machine_position(None) == pytest.approx((-2.5, 1.551, 16.664))
    assert (report.feed, report.spindle) == (500.0, 8000.0)
    later = parse_line("<Run|WPos:-1.000,0.000,0.000|FS:500,0>")
    assert isinstance(later, StatusReport)
    assert later.machine_position(report.wco) == pytest.approx((-1.0, 1.551, 5.664))
    assert later.machine_position(None) is None


@pytest.mark.parametrize(
    ("line", "state", "substate"),
    [
        ("<Hold:0|MPos:1.000,2.000,3.000|FS:0,0>", "Hold", 0),
        ("<Hold:1|MPos:1.000,2.000,3.000|FS:120,0>", "Hold", 1),
        ("<Door:2|MPos:0.000,0.000,0.000|FS:0,0>", "Door", 2),
        ("<Alarm|MPos:0.000,0.000,0.000|FS:0,0>", "Alarm", None),
        ("<Jog|MPos:5.000,0.000,0.000|F:600|Ln:99999|Ov:100,100,100|A:SFM>", "Jog", None),
    ],
)
def test_status_states_and_optional_fields(line: str, state: str, substate: int | None) -> None:
    report = parse_line(line)
    assert isinstance(report, StatusReport)
    assert (report.state, report.substate) == (state, substate)
    if state == "Jog":
        assert (report.feed, report.spindle, report.line_number) == (600.0, None, 99999)
        assert report.overrides == (100, 100, 100)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("ok", Ok()),
        ("error:9", ErrorResponse(9)),
        ("ALARM:1", AlarmMessage(1)),
        ("Grbl 1.1h ['$' for help]", Banner("1.1h")),
        ("Grbl 1.1e ['$' for help]", Banner("1.1e")),
        ("$130=200.000", SettingLine(130, "200.000")),
        ("[MSG:Reset to continue]", Feedback("MSG", "Reset to continue")),
        ("[MSG:Caution: Unlocked]", Feedback("MSG", "Caution: Unlocked")),
        ("[GC:G0 G54 G17 G21 G90 G94 M0 M5 M9 T0 F0. S0.]",
         Feedback("GC", "G0 G54 G17 G21 G90 G94 M0 M5 M9 T0 F0. S0.")),
        ("[VER:v1.1d.20161014:Some string]", Feedback("VER", "v1.1d.20161014:Some string")),
        (">G54G20:ok", StartupLine("G54G20", "ok")),
        (">G54G20:error:20", StartupLine("G54G20", "error:20")),
        ("<Bogus|MPos:0,0,0>", Unrecognised("<Bogus|MPos:0,0,0>")),
        ("<Idle|FS:0,0>", Unrecognised("<Idle|FS:0,0>")),
        ("<Idle|MPos:a,b,c>", Unrecognised("<Idle|MPos:a,b,c>")),
        ("error:x", Unrecognised("error:x")),
        ("\x00\x17noise", Unrecognised("\x00\x17noise")),
    ],
)  # fmt: skip
def test_documented_messages(line: str, expected: object) -> None:
    assert parse_line(line) == expected


def test_error_and_alarm_texts_from_official_tables() -> None:
    assert ErrorResponse(20).text == (
        "Unsupported command: Unsupported or invalid g-code command found in block."
    )
    assert error_text(15) == (
        "Travel exceeded: Jog target exceeds machine travel. Jog command has been ignored."
    )
    assert AlarmMessage(1).text.startswith("Hard limit: Hard limit has been triggered.")
    assert alarm_text(9).startswith("Homing fail: Could not find limit switch")
    assert alarm_text(42) == "unknown alarm code 42 (not in the GRBL 1.1 table)"
    assert sorted(CRITICAL_ALARMS) == [1, 2]
    assert "$H" in alarm_recovery(3) and "$X" in alarm_recovery(3)
    assert alarm_recovery(2).startswith("send a soft reset first")


def test_settings_dump_from_documentation_is_typed() -> None:
    splitter = LineSplitter()
    messages = [parse_line(line) for line in splitter.feed(DOC_SETTINGS_DUMP.encode())]
    assert messages[-1] == Ok()
    settings = GrblSettings.from_lines(m for m in messages if isinstance(m, SettingLine))
    assert settings.status_report_mask == 255
    assert settings.soft_limits is False and settings.homing_enabled is False
    assert settings.homing_seek == 500.0 and settings.homing_pulloff == 1.0
    assert settings.steps_per_mm_x == 250.0
    assert settings.max_rate == pytest.approx(500.0 / 60000.0)
    assert settings.acceleration == pytest.approx(0.010)
    assert settings.travel == pytest.approx(0.2)
    assert settings.step == pytest.approx(4e-6)


def test_setting_validation_names_field_value_range_unit() -> None:
    settings = GrblSettings({22: "0", 110: "500.000"})
    with pytest.raises(ConfigError, match=r"max_rate_x \(\$110\) = 0 is not allowed: must be "
                       r"a number in \(0, 1e\+06\] mm/min"):  # fmt: skip
        settings.check("max_rate_x", 0)
    with pytest.raises(ConfigError, match=r"soft_limits \(\$20\) = True .* homing is disabled"):
        settings.check("soft_limits", True)
    with pytest.raises(ConfigError, match=r"setting = 'speed' is not allowed: must be one of"):
        settings.check("speed", 1)
    with pytest.raises(ConfigError, match=r"step_pulse \(\$0\) = 2.5 .* an integer in \[3, 255\]"):
        settings.check("step_pulse", 2.5)
    assert settings.check("homing_enabled", True) == "$22=1"
    assert settings.updated("max_rate_x", 900.0).max_rate_x == 900.0
    with pytest.raises(AttributeError, match="write_setting"):
        settings.max_rate_x = 1.0
    with pytest.raises(ConfigError, match=r"max_travel_x \(\$130\) = None .* present in the \$\$"):
        _ = settings.max_travel_x


def test_formatting_of_commands() -> None:
    assert format_move_line(-123.4567, 600.0) == "G53 G1 X-123.457 F600.000"
    assert format_jog_line(-0.5, 30.0) == "$J=G91 G21 X-0.500 F30.000"
    assert format_number(-0.0001) == "0.000"


@given(st.lists(st.sampled_from([b"ok", b"error:3", b"<Idle|MPos:0.000,0.000,0.000>",
                                 b"ALARM:2", b"[MSG:Reset to continue]"]), max_size=20),
       st.lists(st.integers(min_value=1, max_value=7), min_size=1, max_size=50))  # fmt: skip
def test_line_splitter_chunking_gives_the_same_lines(lines: list[bytes], cuts: list[int]) -> None:
    stream = b"".join(line + b"\r\n" for line in lines)
    whole = LineSplitter().feed(stream)
    splitter = LineSplitter()
    pieces: list[str] = []
    pos = 0
    for cut in cuts * (len(stream) // max(sum(cuts), 1) + 1):
        pieces += splitter.feed(stream[pos : pos + cut])
        pos += cut
        if pos >= len(stream):
            break
    pieces += splitter.feed(stream[pos:])
    assert whole == [line.decode() for line in lines]
    assert pieces == whole
