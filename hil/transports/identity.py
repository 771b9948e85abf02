"""What a transport resolved to, for the record: the serial device path and, for a USB
device, its vendor:product id, serial number, manufacturer and product (pyserial's
``list_ports`` for a serial port; the URL and the device descriptor for ``usb://``).

>>> port_identity(object())  # a link with nothing to tell (in memory)
{}
"""

from __future__ import annotations

from typing import Any

from hil.transports.base import IdentifiedTransport


def port_identity(transport: object) -> dict[str, str]:
    """``port``, ``usb_vid_pid``, ``usb_serial``, ``manufacturer``, ``product`` as far as
    they are known for ``transport``: its own
    :meth:`~hil.transports.base.IdentifiedTransport.identity` (a
    :class:`~hil.transports.serial_transport.SerialTransport`, a
    :class:`~hil.transports.usb_transport.UsbTransport`, a spy around one), else nothing."""
    return transport.identity() if isinstance(transport, IdentifiedTransport) else {}


def serial_port_identity(path: str) -> dict[str, str]:
    """``port`` (the serial device ``path``) and the USB ids pyserial lists for it (none for
    a pty)."""
    return {"port": path, **_usb_of_serial_port(path)}


def _usb_of_serial_port(path: str) -> dict[str, str]:
    """The USB ids pyserial lists for the serial device ``path`` (none for a pty)."""
    from serial.tools import list_ports

    for info in list_ports.comports():
        if info.device == path and info.vid is not None and info.pid is not None:
            out = {"usb_vid_pid": f"{info.vid:04x}:{info.pid:04x}"}
            named = (
                ("usb_serial", info.serial_number),
                ("manufacturer", info.manufacturer),
                ("product", info.product),
            )
            for key, value in named:
                if value:
                    out[key] = str(value)
            return out
    return {}


def usb_descriptor_identity(device: Any) -> dict[str, str]:
    """``usb_vid_pid`` and the strings of a pyusb ``device``'s descriptor that it answers."""
    out = {"usb_vid_pid": f"{device.idVendor:04x}:{device.idProduct:04x}"}
    for key, attr in (("usb_serial", "serial_number"), ("manufacturer", "manufacturer"),
                      ("product", "product")):  # fmt: skip
        try:
            value = getattr(device, attr)
        except Exception:
            value = None
        if value:
            out[key] = str(value)
    return out
