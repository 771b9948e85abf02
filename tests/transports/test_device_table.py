"""The device table (:mod:`hil.devices.table`): every kind of URL a run names, its roles,
whether it is simulated, its canonical spelling, and each refusal with its message."""

from __future__ import annotations

import pytest

from hil.devices.clock import MonotonicClock
from hil.devices.table import check_device_url, entry_for, is_simulated, open_real_daq
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
