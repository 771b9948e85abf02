"""What is plugged in: serial ports, USB devices, PortAudio and JACK audio devices.

Each finder returns a :class:`Found`: the devices (one dict each, JSON-ready) and a note when
the finder could not look (library or tool missing, no permission), so ``hil devices`` shows
everything it can and says what it could not see. Nothing is opened.

Serial ports and their USB ids come from pyserial's ``list_ports`` (the ids ``hwgrep://``
URLs match); USB devices from pyusb (libusb-1.0); audio devices from PortAudio through
python-sounddevice (JACK appears there as a host API when PortAudio was built with it); the
JACK server's ports from ``jack_lsp``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

BOARD_USB_ID = (0x1209, 0xCA50)
"""USB VID:PID of the transducer board (pid.codes test range)."""


@dataclass
class Found:
    """Devices of one kind, and why the list may be incomplete (``note``; empty if not)."""

    kind: str
    devices: list[dict[str, Any]] = field(default_factory=list)
    note: str = ""


def _usb_id(vid: int | None, pid: int | None) -> str:
    return "" if vid is None or pid is None else f"{vid:04x}:{pid:04x}"


def serial_ports() -> Found:
    """Serial ports (pyserial ``list_ports``) with their USB VID:PID and serial number."""
    from serial.tools import list_ports

    found = Found("serial")
    for port in sorted(list_ports.comports(), key=lambda p: p.device):
        usb_id = _usb_id(port.vid, port.pid)
        found.devices.append({
            "device": port.device,
            "usb_id": usb_id,
            "serial_number": port.serial_number or "",
            "description": port.description if port.description != "n/a" else "",
            "hwid": port.hwid if port.hwid != "n/a" else "",
            "url": f"hwgrep://{usb_id}" if usb_id else port.device,
        })  # fmt: skip
    return found


def usb_devices() -> Found:
    """USB devices (pyusb), the transducer board marked; a note if libusb is missing."""
    found = Found("usb")
    try:
        import usb.core
    except ImportError:
        found.note = "pyusb is not installed: pip install 'cas-hil[usb]'"
        return found
    try:
        devices = list(usb.core.find(find_all=True))
    except usb.core.NoBackendError:
        found.note = "libusb-1.0 is not installed (Debian/Ubuntu: apt-get install libusb-1.0-0)"
        return found
    for dev in sorted(devices, key=lambda d: (d.bus or 0, d.address or 0)):
        vid, pid = int(dev.idVendor), int(dev.idProduct)
        found.devices.append({
            "usb_id": _usb_id(vid, pid),
            "bus": dev.bus,
            "address": dev.address,
            "board": (vid, pid) == BOARD_USB_ID,
            "url": f"usb://{_usb_id(vid, pid)}",
        })  # fmt: skip
    return found


def audio_devices() -> Found:
    """PortAudio devices (python-sounddevice): name, host API, channels, default rate (Hz)."""
    from hil.devices.audio.portaudio_backend import AudioUnavailableError, import_sounddevice

    found = Found("audio")
    try:
        sd = import_sounddevice()
    except AudioUnavailableError as exc:
        found.note = str(exc)
        return found
    apis = [api["name"] for api in sd.query_hostapis()]
    for index, dev in enumerate(sd.query_devices()):
        found.devices.append({
            "index": index,
            "name": dev["name"],
            "host_api": apis[dev["hostapi"]],
            "inputs": int(dev["max_input_channels"]),
            "outputs": int(dev["max_output_channels"]),
            "default_samplerate_hz": float(dev["default_samplerate"]),
        })  # fmt: skip
    return found


def jack_ports_found() -> Found:
    """Ports of the running JACK server (``jack_lsp``); a note without jackd2 or a server."""
    from hil.devices.audio.jack_ports import JackToolError, jack_ports

    found = Found("jack")
    try:
        found.devices = [{"port": port} for port in jack_ports()]
    except (JackToolError, OSError) as exc:
        found.note = str(exc)
    return found


FINDERS = {"serial": serial_ports, "usb": usb_devices, "audio": audio_devices,
           "jack": jack_ports_found}  # fmt: skip
"""Kind -> finder, in the order ``hil devices`` shows them."""


def discover(kinds: tuple[str, ...] = tuple(FINDERS)) -> list[Found]:
    """Run the finders of ``kinds``."""
    return [FINDERS[kind]() for kind in kinds]
