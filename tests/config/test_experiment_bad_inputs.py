"""Experiment files a new user gets wrong, each refused with one line naming what it is, and
every problem of a file reported at once, before anything is opened or moved."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli.main import main
from hil.errors import ConfigError, ConfigErrors
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from sim_devices.acoustics.sound_speed import tank_sound_speed


def _with(old: str, new: str) -> str:
    assert old in DEFAULT_EXPERIMENT
    return DEFAULT_EXPERIMENT.replace(old, new)


def _message(text: str) -> str:
    with pytest.raises(ConfigErrors) as err:
        parse_experiment(text)
    return str(err.value)


def test_a_sound_speed_that_contradicts_the_water_temperature_gives_the_expected_value() -> None:
    text = _with(
        "water_temperature_c = 20.0\n", "water_temperature_c = 20.0\nsound_speed_mps = 1400.0\n"
    )
    assert round(float(tank_sound_speed(20.0)), 1) == 1482.4  # Marczak (1997)
    assert _message(text) == (
        "tank.sound_speed_mps = 1400.0 is not allowed: must be within 10 m/s of 1482.4 m/s, the"
        " sound speed of water at tank.water_temperature_c = 20 °C and salinity 0 ppt; check the"
        " thermometer and the measurement, or give only one of them"
    )


@pytest.mark.parametrize("c", [1475.0, 1482.4, 1492.0])
def test_a_sound_speed_within_the_tolerance_of_the_water_is_used_as_given(c: float) -> None:
    text = _with(
        "water_temperature_c = 20.0\n", f"water_temperature_c = 20.0\nsound_speed_mps = {c}\n"
    )
    assert parse_experiment(text).sound_speed_mps == c


def test_a_sound_speed_alone_is_not_checked_against_the_default_temperature() -> None:
    text = _with("water_temperature_c = 20.0\n", "sound_speed_mps = 1440.0\n")
    exp = parse_experiment(text)
    assert (exp.sound_speed_mps, exp.water_temperature_c) == (1440.0, 20.0)


def test_the_dac_monitor_channel_as_the_board_channel_is_refused() -> None:
    text = _with('stage = "sim://stage"\n', 'stage = "sim://stage"\nboard_channel = 1\n')
    assert _message(text) == (
        "devices.board_channel = 1 is not allowed: must be the hydrophone's channel, not 1;"
        " channel 1 (ADC input 2) is the DAC monitor: it carries the transmitted drive for the"
        " latency measurement; the hydrophone is on 0"
    )


def test_a_receiver_range_shorter_than_the_tow_is_refused() -> None:
    # The target is 8.5 m from the transducer at tow.start_m = -2 m (x = 11 - 2 = 9 m).
    text = _with("max_range_m = 12.0", "max_range_m = 6.0")
    assert _message(text) == (
        "receiver.max_range_m = 6.0 is not allowed: must be >= 8.500 m, the target's range at"
        " tow.start_m = -2 m (the tow's farthest); raise it (or leave it out: the tank's"
        " diagonal), or shorten the tow: beyond it the receiver finds no target"
    )
    assert parse_experiment(_with("max_range_m = 12.0", "max_range_m = 8.5")).max_range_m == 8.5


def test_a_huge_tank_is_refused_under_its_own_key() -> None:
    text = _with("size_m = [12.0, 4.0, 2.5]", "size_m = [1e300, 4.0, 2.5]")
    message = _message(text)
    assert message == "tank.size_m[0] = 1e+300 is not allowed: must be > 0 and <= 1000 m"
    assert "reverberation" not in message


def test_a_pulse_family_is_refused_under_waveform_family_for_gcas() -> None:
    text = _with('family = "random-cyclic"', 'family = "cw-pulse"')
    assert _message(text) == (
        "waveform.family = 'cw-pulse' is not allowed: must be a family of equal hops for"
        " receiver.name = 'gcas-bg'; cw-pulse has hops of 2, 48 ms (a pulse then silence);"
        " use a continuous family (random-cyclic, three-state), or a receiver for pulses (stft)"
    )
    stft = text.replace('name = "gcas-bg"', 'name = "stft"').replace(
        'options = { background = "simulated" }', ""
    )
    assert parse_experiment(stft).waveform.family == "cw-pulse"


@pytest.mark.parametrize(
    ("board", "stage", "message"),
    [
        (
            "sim://stage",
            "sim://board",
            "devices.board = 'sim://stage' is not allowed: must be a DAC/ADC URL (a board's port"
            " or transport URL, audio://DEVICE, sim://board or sim://audio); sim://stage is a"
            " stage; devices.board and devices.stage look swapped: exchange them",
        ),
        (
            "/dev/ttyUSB0",
            "audio://Scarlett?rate=192000",
            "devices.stage = 'audio://Scarlett?rate=192000' is not allowed: must be a stage URL"
            " (a serial port or transport URL, or sim://stage); audio://Scarlett is a DAC/ADC;"
            " devices.board and devices.stage look swapped: exchange them",
        ),
    ],
)
def test_board_and_stage_urls_swapped_are_named_as_swapped(
    board: str, stage: str, message: str
) -> None:
    old = 'board = "sim://board"\nstage = "sim://stage"'
    assert _message(_with(old, f'board = "{board}"\nstage = "{stage}"')) == message


def test_a_stage_url_as_the_board_alone_is_not_called_swapped() -> None:
    old = 'board = "sim://board"\nstage = "sim://stage"'
    message = _message(_with(old, 'board = "sim://stage"\nstage = "sim://stage"'))
    assert message.endswith("sim://stage is a stage")


def test_a_max_duration_shorter_than_the_tow_is_refused() -> None:
    # One pass of 3 m plus 0.6 m run-up and run-down at 1.5 m/s: 2.8 s at least.
    text = _with('output_dir = "runs"\n', 'output_dir = "runs"\nmax_duration_s = 2.5\n')
    assert _message(text) == (
        "run.max_duration_s = 2.5 is not allowed: must be >= 2.8 s, the tow's shortest duration"
        " (tow.repeats x (|end_m - start_m| + run_up_m + run_down_m) / speed_mps); raise it:"
        " the run is stopped as a failure when it runs out"
    )
    ok = _with('output_dir = "runs"\n', 'output_dir = "runs"\nmax_duration_s = 2.8\n')
    assert parse_experiment(ok).max_duration_s == 2.8


def test_every_problem_of_a_file_is_reported_at_once() -> None:
    text = (
        _with("speed_mps = 1.5", "speed_mps = -1.5")
        .replace("m_hops = 10", "m_hops = 0")
        .replace("late_tail = true", 'late_tail = "yes"')
        .replace("repeats = 1", "repeat = 1")
    )
    with pytest.raises(ConfigErrors) as err:
        parse_experiment(text)
    assert [e.field for e in err.value.errors] == [
        "tow.repeat",
        "tow.speed_mps",
        "receiver.m_hops",
        "simulation.late_tail",
    ]
    assert str(err.value).splitlines() == [str(e) for e in err.value.errors]
    assert isinstance(err.value, ConfigError) and err.value.field == "tow.repeat"


@pytest.mark.parametrize(
    ("old", "new", "first_line"),
    [
        (
            'output_dir = "runs"\n',
            'output_dir = "runs"\nmax_duration_s = 1.0\n',
            "run.max_duration_s = 1.0 is not allowed: must be >= 2.8 s",
        ),
        ("max_range_m = 12.0", "max_range_m = 3.0", "receiver.max_range_m = 3.0 is not allowed"),
    ],
)
def test_the_command_refuses_before_any_device_opens(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str, first_line: str
) -> None:
    path = tmp_path / "exp.toml"
    path.write_text(_with(old, new).replace("late_tail = true", 'late_tail = "yes"'), "utf-8")
    out = tmp_path / "run"
    assert main(["tank-run", str(path), "--out", str(out)]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2
    assert lines[0] == (
        "hil tank-run: error: simulation.late_tail = 'yes' is not allowed: must be true or false"
        " (a TOML boolean, unquoted); write late_tail = true"
    )
    assert lines[1].startswith(f"hil tank-run: error: {first_line}")
    assert not out.exists()  # no run folder: nothing opened, nothing moved
