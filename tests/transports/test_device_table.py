"""The device table (:mod:`hil.devices.table`): every kind of URL a run names, its roles,
whether it is simulated, its canonical spelling, and each refusal with its message."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.devices.clock import MonotonicClock
from hil.devices.table import (
    audio_interface_url,
    check_device_url,
    entry_for,
    is_simulated,
    open_audio_interface,
    open_real_daq,
    open_stage,
)
from hil.errors import ConfigError


@pytest.mark.parametrize(
    ("url", "name", "roles", "simulated"),
    [
        ("/dev/ttyACM0", "transport", ("daq", "stage"), False),
        ("serial:///dev/ttyUSB0?baud=115200", "transport", ("daq", "stage"), False),
        ("usb://1209:ca50", "transport", ("daq", "stage"), False),
        ("hwgrep://2341:", "transport", ("daq", "stage"), False),
        ("spy://loop://?file=t.log", "transport", ("daq", "stage"), False),
        ("sim://board?impl=c", "sim://board", ("daq",), True),
        ("sim://stage?via=memory", "sim://stage", ("stage",), True),
        ("sim://audio?blocksize=256", "sim://audio", ("daq",), True),
        ("audio://sim?blocksize=256", "sim://audio", ("daq",), True),
        ("audio://Scarlett%202i2?rate=192000", "audio://", ("daq",), False),
    ],
)
def test_every_kind_of_url_has_one_row(
    url: str, name: str, roles: tuple[str, ...], simulated: bool
) -> None:
    entry = entry_for(url)
    assert (entry.name, entry.roles, entry.simulated) == (name, roles, simulated)
    assert is_simulated(url) is simulated


@pytest.mark.parametrize(
    ("url", "role", "canonical"),
    [
        ("audio://sim?rate=192000", "daq", "sim://audio?rate=192000"),
        ("sim://audio", "daq", "sim://audio"),
        ("audio://JACK?rate=48000&blocksize=512", "daq", "audio://JACK?rate=48000&blocksize=512"),
        ("serial:///dev/ttyACM0", "daq", "serial:///dev/ttyACM0"),
        ("/dev/ttyUSB0", "stage", "/dev/ttyUSB0"),
        ("sim://stage", "stage", "sim://stage"),
    ],
)
def test_a_url_checks_to_its_canonical_spelling(url: str, role: str, canonical: str) -> None:
    assert check_device_url(url, role) == canonical


@pytest.mark.parametrize(
    ("url", "role", "message"),
    [
        ("sim://audio", "stage", "devices.stage = 'sim://audio' is not allowed: must be a stage"
         " URL (a serial port or transport URL, or sim://stage); sim://audio is a DAC/ADC"),
        ("sim://stage", "daq", "devices.board = 'sim://stage' is not allowed: must be a DAC/ADC"
         " URL (a board's port or transport URL, audio://DEVICE, sim://board or sim://audio);"
         " sim://stage is a stage"),
        ("audio://JACK", "stage", "devices.stage = 'audio://JACK' is not allowed: must be a"
         " stage URL (a serial port or transport URL, or sim://stage); audio://JACK is a"
         " DAC/ADC"),
        ("sim://stge", "stage", "devices.stage = 'sim://stge' is not allowed: must be"
         " sim://stage (a simulated stage); did you mean sim://stage?"),
        ("ftp://x", "daq", "devices.board = 'ftp://x' is not allowed: must be a device path or"
         " one of serial://"),
        ("", "daq", "devices.board = '' is not allowed: must be a non-empty transport URL"),
        ("sim://board", "motor", "role = 'motor' is not allowed: must be one of daq, stage"),
    ],
)  # fmt: skip
def test_a_url_that_cannot_fill_the_role_is_refused(url: str, role: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        check_device_url(url, role)
    assert str(err.value).startswith(message)


def test_a_simulated_daq_is_not_opened_as_a_real_one() -> None:
    with pytest.raises(ConfigError) as err:
        open_real_daq("sim://audio", 192_000.0, MonotonicClock(), 1000)
    assert str(err.value) == (
        "devices.board = 'sim://audio' is not allowed: must be a real DAC/ADC; simulated"
        " devices run in the built-in tank"
    )


def test_a_stage_opens_through_the_table_and_answers() -> None:
    from hil.devices.grbl import GrblStage
    from sim_devices.stage import GrblSimConfig, ManualClock

    config = GrblSimConfig(max_travel_mm=300.0)
    with open_stage(
        "sim://stage?via=memory",
        clock=ManualClock(0.0),
        wait_step=0.5,
        transport_options={"config": config},
    ) as stage:
        assert isinstance(stage, GrblStage)
        assert stage.limits == (-0.3, 0.0)  # its $130 = 300 mm, read on connecting
        assert stage.status().state.name == "IDLE"


@pytest.mark.parametrize(
    ("url", "field", "message"),
    [
        ("sim://audio", "--url", "--url = 'sim://audio' is not allowed: must be a stage URL"),
        ("sim://board", "devices.stage", "devices.stage = 'sim://board' is not allowed: must be"
         " a stage URL (a serial port or transport URL, or sim://stage); sim://board is a"
         " DAC/ADC"),
        ("", "url", "url = '' is not allowed: must be a non-empty transport URL"),
    ],
)  # fmt: skip
def test_a_stage_url_that_names_no_stage_is_refused_before_opening(
    url: str, field: str, message: str
) -> None:
    with pytest.raises(ConfigError) as err:
        open_stage(url, field=field)
    assert str(err.value).startswith(message)


@pytest.mark.parametrize(
    ("device", "url"),
    [
        ("Scarlett 2i2", "audio://Scarlett%202i2"),
        ("2", "audio://2"),
        ("audio://JACK?rate=48000", "audio://JACK?rate=48000"),
        ("audio://sim?delay=3", "sim://audio?delay=3"),
        ("sim://audio", "sim://audio"),
    ],
)
def test_an_audio_interface_has_one_spelling(device: str, url: str) -> None:
    assert audio_interface_url(device) == url


@pytest.mark.parametrize(
    ("device", "message"),
    [
        ("sim://board", "--device = 'sim://board' is not allowed: must be an audio interface"
         " name, index, audio://DEVICE or sim://audio"),
        ("serial:///dev/ttyACM0", "--device = 'serial:///dev/ttyACM0' is not allowed: must"
         " be an audio interface"),
        (" ", "--device = ' ' is not allowed: must be an audio interface name, index or"
         " audio:// URL"),
        ("audio://JACK?rate=fast", "devices.board rate = 'fast' is not allowed"),
    ],
)  # fmt: skip
def test_a_device_that_is_no_audio_interface_is_refused(device: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        audio_interface_url(device)
    assert str(err.value).startswith(message)


def test_the_simulated_interface_is_not_opened_as_a_real_one() -> None:
    with pytest.raises(ConfigError) as err:
        open_audio_interface("sim://audio", samplerate=48000.0, channels_in=1, blocksize=256)
    assert str(err.value) == (
        "--device = 'sim://audio' is not allowed: must be a real audio interface;"
        " sim://audio is simulated"
    )


def test_a_real_interface_opens_with_the_settings_asked_for() -> None:
    duplex = open_audio_interface(
        "Scarlett 2i2", samplerate=96000.0, channels_in=2, blocksize=512
    )  # not opened: no interface needed
    s = duplex.settings
    assert (s.device, s.samplerate, s.channels_in, s.channels_out, s.blocksize, s.latency) == (
        "Scarlett 2i2", 96000.0, 2, 1, 512, "low"
    )  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["stage", "status", "--url", "sim://audio"],
         "hil stage: error: --url = 'sim://audio' is not allowed: must be a stage URL (a serial"
         " port or transport URL, or sim://stage); sim://audio is a DAC/ADC"),
        (["calibrate", "latency", "--device", "sim://board"],
         "hil calibrate: error: --device = 'sim://board' is not allowed: must be an audio"
         " interface name, index, audio://DEVICE or sim://audio"),
    ],
)  # fmt: skip
def test_the_commands_refuse_a_device_of_the_wrong_kind_through_the_table(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from hil.cli.main import main

    store = ["--store", str(tmp_path)] if argv[0] == "calibrate" else []
    assert main([*argv, *store]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith(message)
