"""Stream settings: every bad value is refused with the field, the value and the range."""

from __future__ import annotations

from typing import Any

import pytest

from hil.devices.audio import AudioSettings, DeviceInfo, find_device
from hil.errors import ConfigError

DEVICES = [
    DeviceInfo(0, "system", "JACK Audio Connection Kit", 2, 2, 192000.0),
    DeviceInfo(1, "USB Audio CODEC: Audio (hw:1,0)", "ALSA", 2, 2, 48000.0),
    DeviceInfo(2, "USB Audio CODEC: Audio (hw:2,0)", "ALSA", 1, 0, 48000.0),
    DeviceInfo(3, "HDMI", "ALSA", 0, 8, 48000.0),
]


def test_defaults_and_block_duration() -> None:
    s = AudioSettings()
    assert (s.samplerate, s.channels_in, s.channels_out, s.blocksize, s.latency, s.device) == (
        48000.0,
        1,
        1,
        256,
        "low",
        None,
    )
    assert AudioSettings(samplerate=192000, blocksize=256).block_duration_s == 256 / 192000


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"blocksize": 0},
            "blocksize = 0 is not allowed: must be an integer in [16, 65536] frames; use a fixed "
            "block size such as 256 (0 = variable blocks is not supported: the loopback latency "
            "would change from run to run)",
        ),
        ({"blocksize": 100000}, "blocksize = 100000 is not allowed: must be an integer in [16,"),
        ({"blocksize": 256.0}, "blocksize = 256.0 is not allowed"),
        (
            {"samplerate": 0},
            "samplerate = 0 is not allowed: must be a number of Hz in [1000, 768000]; use the rate "
            "the interface (or the JACK server) runs at, e.g. 48000",
        ),
        ({"samplerate": float("nan")}, "samplerate = nan is not allowed"),
        ({"samplerate": True}, "samplerate = True is not allowed"),
        (
            {"channels_in": 0},
            "channels_in = 0 is not allowed: must be an integer in [1, 256]; count the connected "
            "channels",
        ),
        (
            {"channels_out": 2.0},
            "channels_out = 2.0 is not allowed: must be an integer in [1, 256]",
        ),
        (
            {"latency": "medium"},
            "latency = 'medium' is not allowed: must be 'low', 'high' or seconds in [0, 2]; it is "
            "only a hint to the driver; the loopback latency is measured anyway",
        ),
        ({"latency": -0.1}, "latency = -0.1 is not allowed"),
        ({"latency": float("inf")}, "latency = inf is not allowed"),
        (
            {"device": -1},
            "device = -1 is not allowed: must be None, a device index >= 0 or a name substring; "
            "list the devices with `python -m sounddevice`",
        ),
        ({"device": 1.5}, "device = 1.5 is not allowed"),
    ],
)
def test_bad_settings_are_refused(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as err:
        AudioSettings(**kwargs)
    assert str(err.value).startswith(message)


def test_find_device_by_index_substring_host_api_and_default() -> None:
    assert find_device(0, DEVICES, 2, 2).name == "system"
    assert find_device("jack", DEVICES, 2, 2).index == 0
    assert find_device("hw:1", DEVICES, 2, 2).index == 1
    assert find_device("SYSTEM", DEVICES, 1, 1).index == 0  # exact name, any case
    assert find_device(None, DEVICES, 1, 1).index == 0  # first full-duplex device
    # Only devices with enough channels are candidates: "USB Audio" names 2, only 1 fits.
    assert find_device("USB Audio", DEVICES, 2, 2).index == 1


def test_unknown_device_name_lists_every_device() -> None:
    with pytest.raises(ConfigError) as err:
        find_device("Scarlett", DEVICES, 1, 1)
    assert str(err.value) == (
        "device = 'Scarlett' is not allowed: must be an index or a name substring of a device "
        "with >= 1 in and >= 1 out: 0 'system' (JACK Audio Connection Kit, 2 in, 2 out); "
        "1 'USB Audio CODEC: Audio (hw:1,0)' (ALSA, 2 in, 2 out); "
        "2 'USB Audio CODEC: Audio (hw:2,0)' (ALSA, 1 in, 0 out); 3 'HDMI' (ALSA, 0 in, 8 out); "
        "is the interface plugged in (or the JACK server running)? `python -m sounddevice` "
        "lists the devices"
    )


def test_unknown_device_index_and_empty_device_list() -> None:
    with pytest.raises(ConfigError, match=r"^device = 9 is not allowed: must be an index"):
        find_device(9, DEVICES, 1, 1)
    with pytest.raises(ConfigError, match=r"PortAudio lists no device"):
        find_device(None, [], 1, 1)


def test_ambiguous_device_name_asks_for_an_index() -> None:
    wide = [*DEVICES, DeviceInfo(4, "USB Audio CODEC: Audio (hw:3,0)", "ALSA", 2, 2, 48000.0)]
    with pytest.raises(ConfigError) as err:
        find_device("usb audio", wide, 1, 1)
    assert str(err.value) == (
        "device = 'usb audio' is not allowed: must be a name matching one device, not several: "
        "1 'USB Audio CODEC: Audio (hw:1,0)' (ALSA, 2 in, 2 out); "
        "4 'USB Audio CODEC: Audio (hw:3,0)' (ALSA, 2 in, 2 out); use an index"
    )


def test_device_index_without_enough_channels() -> None:
    with pytest.raises(ConfigError) as err:
        find_device(3, DEVICES, 1, 2)
    assert str(err.value) == (
        "channels_in/channels_out = (1, 2) is not allowed: must be at most (0, 8) on "
        "3 'HDMI' (ALSA, 0 in, 8 out); lower the channel counts or pick another device"
    )
