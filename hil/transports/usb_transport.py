"""``usb://VID:PID``: a board's bulk endpoints through pyusb.

The real backend is libusb-1.0 through pyusb (``usb.backend.libusb1``; Debian package
``libusb-1.0-0``; the user needs permission on the device node, e.g. a udev rule). Tests pass
a backend object instead (``backend=``): :class:`sim_devices.board.usb_backend.
SimulatedUsbBackend` implements the simulated board behind pyusb's ``IBackend`` interface,
so the same :class:`UsbTransport` code runs against it.

The interface's first bulk OUT and first bulk IN endpoints carry the byte stream.
"""

from __future__ import annotations

import contextlib
from typing import Any

from hil.errors import ConfigError
from hil.transports.base import TransportClosedError, TransportOpenError, TransportTimeoutError

_BACKENDS = ("libusb1", "libusb0", "openusb")
_READ_SIZE = 16384  # a multiple of every bulk packet size (64, 512, 1024)


def named_backend(name: str) -> Any:
    """The pyusb backend called ``name`` (libusb1, libusb0, openusb), or raise."""
    if name not in _BACKENDS:
        raise ConfigError("usb backend", name, f"one of {', '.join(_BACKENDS)}")
    import importlib

    module = importlib.import_module(f"usb.backend.{name}")
    backend = module.get_backend()
    if backend is None:
        raise TransportOpenError(
            f"pyusb backend {name} is not available: its system library is missing; install"
            " libusb-1.0 (Debian/Ubuntu: apt-get install libusb-1.0-0)"
        )
    return backend


class UsbTransport:
    """Bulk IN/OUT endpoints of one USB interface with the transport contract.

    Parameters
    ----------
    vendor_id, product_id:
        Which device (the first one found).
    interface:
        bInterfaceNumber of the interface holding the bulk endpoints.
    backend:
        A pyusb backend object (default: pyusb's choice, libusb-1.0 first).
    timeout:
        Seconds one read may wait.
    """

    def __init__(
        self,
        vendor_id: int,
        product_id: int,
        *,
        interface: int = 0,
        backend: Any = None,
        timeout: float = 0.05,
        url: str | None = None,
    ) -> None:
        self.url = url or f"usb://{vendor_id:04x}:{product_id:04x}"
        try:
            import usb.core
            import usb.util
        except ImportError as error:
            raise TransportOpenError(
                f"{self.url}: pyusb is not installed; pip install 'cas-hil[usb]'"
            ) from error
        self.timeout = timeout
        self.interface = interface
        try:
            dev = usb.core.find(idVendor=vendor_id, idProduct=product_id, backend=backend)
        except usb.core.NoBackendError as error:
            raise TransportOpenError(
                f"{self.url}: no pyusb backend is available; install libusb-1.0 (Debian/Ubuntu:"
                " apt-get install libusb-1.0-0)"
            ) from error
        if dev is None:
            raise TransportOpenError(
                f"{self.url}: no USB device {vendor_id:04x}:{product_id:04x} found; check the"
                " cable and power, `lsusb`, and that a udev rule gives you access"
            )
        try:
            with contextlib.suppress(NotImplementedError, usb.core.USBError):
                if dev.is_kernel_driver_active(interface):
                    dev.detach_kernel_driver(interface)
            dev.set_configuration()
            intf = dev.get_active_configuration()[(interface, 0)]
            self._ep_out = self._bulk_endpoint(intf, usb.util.ENDPOINT_OUT)
            self._ep_in = self._bulk_endpoint(intf, usb.util.ENDPOINT_IN)
            usb.util.claim_interface(dev, interface)
        except usb.core.USBError as error:
            usb.util.dispose_resources(dev)
            raise TransportOpenError(f"{self.url}: cannot claim the device ({error})") from error
        self._dev = dev
        self.closed = False

    def _bulk_endpoint(self, intf: Any, direction: int) -> Any:
        import usb.util

        def wanted(ep: Any) -> bool:
            return bool(
                usb.util.endpoint_direction(ep.bEndpointAddress) == direction
                and usb.util.endpoint_type(ep.bmAttributes) == usb.util.ENDPOINT_TYPE_BULK
            )

        ep = usb.util.find_descriptor(intf, custom_match=wanted)
        if ep is None:
            which = "IN" if direction == usb.util.ENDPOINT_IN else "OUT"
            raise TransportOpenError(
                f"{self.url}: interface {self.interface} has no bulk {which} endpoint; is this"
                " the board's data interface? (set ?interface=N)"
            )
        return ep

    def _timeout_ms(self) -> int:
        return max(1, round(self.timeout * 1000))  # 0 would mean "forever" to libusb

    def read(self, size: int) -> bytes:
        """Up to ``size`` bytes from the bulk IN endpoint; ``b""`` after the timeout."""
        import usb.core

        try:
            data = self._dev.read(self._ep_in, min(size, _READ_SIZE), self._timeout_ms())
        except usb.core.USBTimeoutError:
            return b""
        except usb.core.USBError as error:
            raise TransportClosedError(f"{self.url}: link lost while reading ({error})") from error
        return bytes(data.tobytes())

    def write(self, data: bytes) -> int:
        """Send all of ``data`` on the bulk OUT endpoint."""
        import usb.core

        try:
            written = int(self._dev.write(self._ep_out, data, 5000))
        except usb.core.USBTimeoutError as error:
            raise TransportTimeoutError(f"{self.url}: bulk write timed out") from error
        except usb.core.USBError as error:
            raise TransportClosedError(f"{self.url}: link lost while writing ({error})") from error
        return written

    def identity(self) -> dict[str, str]:
        """The device's vendor:product id and the descriptor strings it answers."""
        from hil.transports.identity import usb_descriptor_identity

        return usb_descriptor_identity(self._dev)

    def close(self) -> None:
        """Release the interface and the device handle; idempotent."""
        if self.closed:
            return
        self.closed = True
        import usb.util

        with contextlib.suppress(Exception):
            usb.util.dispose_resources(self._dev)
