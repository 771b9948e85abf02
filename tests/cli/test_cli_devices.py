"""``hil devices`` lists what pyserial, pyusb, PortAudio and JACK see, and says what it could
not look at; ``hwgrep://`` URLs resolve through pyserial's port search."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
from serial.tools import list_ports

from hil.cli.main import main
from hil.devices.audio.portaudio_backend import portaudio_available
from hil.devices.discovery import BOARD_USB_ID, audio_devices, usb_devices
from hil.errors import ConfigError
from hil.transports.registry import open_transport, resolve_hwgrep


def _devices(capsys: pytest.CaptureFixture[str], *kinds: str) -> dict:  # type: ignore[type-arg]
    assert main(["devices", *kinds, "--json"]) == 0
    return json.loads(capsys.readouterr().out)  # type: ignore[no-any-return]


def test_serial_ports_are_pyserials_with_their_usb_ids(capsys: pytest.CaptureFixture[str]) -> None:
    found = _devices(capsys, "serial")["serial"]
    expected = sorted(list_ports.comports(), key=lambda p: p.device)
    assert [d["device"] for d in found["devices"]] == [p.device for p in expected]
    for d, p in zip(found["devices"], expected, strict=True):
        usb_id = f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None else ""
        assert d["usb_id"] == usb_id
        assert d["url"] == (f"hwgrep://{usb_id}" if usb_id else p.device)
    assert found["note"] == ""


def test_usb_list_or_a_note_saying_why_not() -> None:
    found = usb_devices()
    if found.note:
        assert found.devices == [] and ("pyusb" in found.note or "libusb" in found.note)
    for d in found.devices:
        assert d["url"] == f"usb://{d['usb_id']}"
        assert d["board"] == (d["usb_id"] == f"{BOARD_USB_ID[0]:04x}:{BOARD_USB_ID[1]:04x}")


def test_audio_list_or_the_portaudio_hint() -> None:
    available, why = portaudio_available()
    found = audio_devices()
    if available:
        import sounddevice

        assert len(found.devices) == len(sounddevice.query_devices()) and found.note == ""
    else:
        assert found.devices == [] and found.note == why
        assert "apt-get install libportaudio2" in found.note


def test_every_kind_is_reported_even_when_a_library_is_missing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert set(_devices(capsys)) == {"serial", "usb", "audio", "jack"}
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    for kind in ("serial", "usb", "audio", "jack"):
        assert f"\n{kind}: " in f"\n{out}"


def test_unknown_kind_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["devices", "seriel"]) == 2
    assert capsys.readouterr().err.strip() == (
        "hil devices: error: KIND = 'seriel' is not allowed: must be one of serial, usb, audio, "
        "jack; or none for all"
    )


def test_hwgrep_matching_nothing_names_the_ports() -> None:
    with pytest.raises(ConfigError) as err:
        open_transport("hwgrep://no-such-port-xyz")
    message = str(err.value)
    assert message.startswith(
        "url = 'hwgrep://no-such-port-xyz' is not allowed: must be a regexp matching at least "
        "1 serial port(s); 0 match; ports on this machine: "
    )
    assert message.endswith("; see hil devices")


def test_hwgrep_resolves_through_pyserials_search() -> None:
    ports = sorted(list_ports.comports(), key=lambda p: p.device)
    if not ports:
        pytest.skip("no serial port on this machine to match")
    name = ports[0].device.rsplit("/", 1)[-1]
    device, baud = resolve_hwgrep(f"hwgrep://{name}$&baud=921600")
    assert device == ports[0].device and baud == 921600
    with pytest.raises(ConfigError, match="hwgrep:// option = 'speed'"):
        resolve_hwgrep(f"hwgrep://{name}&speed=3")


JACK_NOISE = (
    "Cannot connect to server socket err = No such file or directory\n"
    "Cannot connect to server request channel\n"
    "jack server is not running or cannot be started\n"
    "JackShmReadWritePtr::~JackShmReadWritePtr - Init not done for -1, skipping unlock\n"
)


def test_without_a_jack_server_the_jack_line_is_one_readable_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """``jack_lsp`` prints libjack's internals before its error: only the error is shown."""
    tool = tmp_path / "jack_lsp"
    tool.write_text(
        "#!/bin/sh\n"
        f"printf '{JACK_NOISE}' >&2\n"
        "echo 'Error: cannot connect to JACK, server is not running.' >&2\n"
        "exit 1\n"
    )
    tool.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    assert main(["devices", "jack"]) == 0
    out, err = capfd.readouterr()
    assert out == (
        "jack: 0 found (jack_lsp failed with status 1: cannot connect to JACK, server is not "
        "running; is the JACK server running?)\n"
    )
    assert err == ""


def test_portaudio_initialising_prints_nothing_of_jacks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """PortAudio's JACK host API has libjack write on fd 2 as sounddevice is imported (no
    server): held back, so `hil devices audio` shows only its own lines."""
    fake = tmp_path / "sounddevice.py"
    fake.write_text(
        "import os\n"
        f"os.write(2, {JACK_NOISE.encode()!r})\n"
        "def query_hostapis():\n    return [{'name': 'JACK Audio Connection Kit'}]\n"
        "def query_devices():\n"
        "    return [{'name': 'system', 'hostapi': 0, 'max_input_channels': 2,\n"
        "             'max_output_channels': 2, 'default_samplerate': 48000.0}]\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "sounddevice", raising=False)
    assert main(["devices", "audio"]) == 0
    out, err = capfd.readouterr()
    assert out == (
        "audio: 1 found\n    0 'system' (JACK Audio Connection Kit): 2 in, 2 out, 48000 Hz\n"
    )
    assert err == ""
