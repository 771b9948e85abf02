"""``hil devices``: list serial ports, USB devices, PortAudio devices and JACK ports.

Examples::

    hil devices                 # everything, as tables
    hil devices serial usb      # some kinds
    hil devices --json          # one JSON object: kind -> {devices, note}

Each line gives the URL or name to use: a serial port's ``hwgrep://VID:PID`` (or its
path) for ``devices.stage`` / ``devices.board``, a USB board's ``usb://VID:PID``, an audio
device's name for ``--device``. Nothing is opened.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from hil.errors import ConfigError

KINDS = ("serial", "usb", "audio", "jack")


def register(sub: Any) -> None:
    """Add the ``devices`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "devices",
        help="list serial ports, USB devices, PortAudio and JACK devices",
        description="List what is plugged in, with the URL or name each device is used by "
        "(hwgrep://VID:PID or the path of a serial port, usb://VID:PID of a USB board, the "
        "name of an audio device for --device). Says what it could not look at (a library "
        "or tool missing). Nothing is opened.",
        epilog="Kinds: serial (pyserial list_ports, with USB VID:PID), usb (pyusb, needs "
        "libusb-1.0), audio (PortAudio through python-sounddevice, JACK as a host API), jack "
        "(ports of the running JACK server, jack_lsp).",
    )
    p.add_argument(
        "kinds", nargs="*", metavar="KIND",
        help=f"kinds to list, among {', '.join(KINDS)} (default: all)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _row(kind: str, d: dict[str, Any]) -> str:
    if kind == "serial":
        extra = " ".join(v for v in (d["usb_id"], d["serial_number"], d["description"]) if v)
        return f"{d['device']:<16} {extra or '(no hardware id)'}  -> {d['url']}"
    if kind == "usb":
        mark = "  <- the transducer board" if d["board"] else ""
        return f"bus {d['bus']:>3} addr {d['address']:>3}  {d['usb_id']}  -> {d['url']}{mark}"
    if kind == "audio":
        return (f"{d['index']:>3} {d['name']!r} ({d['host_api']}): {d['inputs']} in, "
                f"{d['outputs']} out, {d['default_samplerate_hz']:g} Hz")  # fmt: skip
    return str(d["port"])


def run(args: argparse.Namespace) -> int:
    """Execute ``hil devices``; return the exit status."""
    from hil.devices.discovery import discover

    unknown = [k for k in args.kinds if k not in KINDS]
    if unknown:
        raise ConfigError("KIND", unknown[0], f"one of {', '.join(KINDS)}", "or none for all")
    found = discover(tuple(args.kinds) or KINDS)
    if args.json:
        print(json.dumps({f.kind: {"devices": f.devices, "note": f.note} for f in found}))
        return 0
    for f in found:
        print(f"{f.kind}: {len(f.devices)} found" + (f" ({f.note})" if f.note else ""))
        for d in f.devices:
            print(f"  {_row(f.kind, d)}")
    return 0
