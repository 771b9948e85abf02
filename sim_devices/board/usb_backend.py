"""The simulated board as a pyusb backend: what libusb would be for a real board.

:class:`SimulatedUsbBackend` implements :class:`usb.backend.IBackend` (enumerate_devices,
the four descriptor getters, open/close, configuration, interface claiming, bulk
transfers), so ``usb.core.find(idVendor=..., backend=SimulatedUsbBackend(board))`` returns
a real :class:`usb.core.Device` whose bulk endpoints talk to the simulated firmware. The
real backend is libusb-1.0 (pyusb's default, ``usb.backend.libusb1``); tests inject this one.

Device layout: VID:PID ``1209:CA50`` (pid.codes test range), one configuration, interface 0
(vendor class 0xFF) with bulk OUT endpoint 0x01 and bulk IN endpoint 0x81, 512-byte packets
(high speed). A read with nothing to deliver raises ``USBTimeoutError`` after its timeout,
as libusb does; after ``faults.disconnect()`` every call raises ``USBError`` (ENODEV) and the
device disappears from enumeration until ``faults.replug()``.

>>> import usb.core
>>> backend = SimulatedUsbBackend(SimulatedBoard())
>>> dev = usb.core.find(idVendor=VENDOR_ID, idProduct=PRODUCT_ID, backend=backend)
>>> hex(dev.idVendor), [hex(e.bEndpointAddress) for e in dev.get_active_configuration()[(0, 0)]]
('0x1209', ['0x1', '0x81'])
"""

from __future__ import annotations

import array
import errno
from collections.abc import Iterator
from typing import Any

import usb.backend
import usb.core

from hil.errors import TransportClosedError
from sim_devices.board.core import SimulatedBoard
from sim_devices.board.port import BoardPort

VENDOR_ID = 0x1209
PRODUCT_ID = 0xCA50
EP_OUT = 0x01
EP_IN = 0x81
PACKET_SIZE = 512
_BULK = 0x02


class _Descriptor:
    """A descriptor: its fields as attributes (what pyusb reads from a backend)."""

    def __init__(self, **fields: Any) -> None:
        self.__dict__.update(fields)


class _DeviceId:
    """Opaque device identification yielded by enumerate_devices."""


def _no_device(what: str) -> usb.core.USBError:
    return usb.core.USBError(f"No such device ({what})", error_code=-4, errno=errno.ENODEV)


class SimulatedUsbBackend(usb.backend.IBackend):
    """pyusb backend whose single device is ``board`` (see the module docstring).

    Parameters
    ----------
    board:
        The simulated board firmware (default: a new :class:`SimulatedBoard`).
    vendor_id, product_id:
        What the device enumerates as.
    """

    def __init__(
        self,
        board: SimulatedBoard | None = None,
        *,
        vendor_id: int = VENDOR_ID,
        product_id: int = PRODUCT_ID,
    ) -> None:
        super().__init__()
        self.port = BoardPort(board or SimulatedBoard())
        self.vendor_id = vendor_id
        self.product_id = product_id
        self._dev = _DeviceId()
        self.opened = 0

    @property
    def board(self) -> SimulatedBoard:
        """The simulated firmware (hold ``port.lock`` to poke it from another thread)."""
        return self.port.board

    # --- enumeration and descriptors -------------------------------------------------------
    def enumerate_devices(self) -> Iterator[_DeviceId]:
        if not self.board.faults.unplugged:
            yield self._dev

    def get_device_descriptor(self, dev: _DeviceId) -> _Descriptor:
        return _Descriptor(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0200,
            bDeviceClass=0,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=self.vendor_id,
            idProduct=self.product_id,
            bcdDevice=0x0100,
            iManufacturer=0,
            iProduct=0,
            iSerialNumber=0,
            bNumConfigurations=1,
            address=1,
            bus=1,
            port_number=1,
            port_numbers=(1,),
            speed=3,  # high speed
        )

    def get_configuration_descriptor(self, dev: _DeviceId, config: int) -> _Descriptor:
        return _Descriptor(
            bLength=9,
            bDescriptorType=2,
            wTotalLength=9 + 9 + 2 * 7,
            bNumInterfaces=1,
            bConfigurationValue=1,
            iConfiguration=0,
            bmAttributes=0x80,
            bMaxPower=50,
            extra_descriptors=[],
        )

    def get_interface_descriptor(
        self, dev: _DeviceId, intf: int, alt: int, config: int
    ) -> _Descriptor:
        if intf != 0 or alt != 0:
            raise IndexError("the simulated board has one interface (0) with one setting (0)")
        return _Descriptor(
            bLength=9,
            bDescriptorType=4,
            bInterfaceNumber=0,
            bAlternateSetting=0,
            bNumEndpoints=2,
            bInterfaceClass=0xFF,
            bInterfaceSubClass=0,
            bInterfaceProtocol=0,
            iInterface=0,
            extra_descriptors=[],
        )

    def get_endpoint_descriptor(
        self, dev: _DeviceId, ep: int, intf: int, alt: int, config: int
    ) -> _Descriptor:
        if ep not in (0, 1):
            raise IndexError("the simulated board has two endpoints (0: OUT 0x01, 1: IN 0x81)")
        return _Descriptor(
            bLength=7,
            bDescriptorType=5,
            bEndpointAddress=(EP_OUT, EP_IN)[ep],
            bmAttributes=_BULK,
            wMaxPacketSize=PACKET_SIZE,
            bInterval=0,
            bRefresh=0,
            bSynchAddress=0,
            extra_descriptors=[],
        )

    # --- handles and configuration ---------------------------------------------------------
    def open_device(self, dev: _DeviceId) -> BoardPort:
        try:
            self.port.open()
        except TransportClosedError:
            raise _no_device("open") from None
        self.opened += 1
        return self.port

    def close_device(self, dev_handle: BoardPort) -> None:
        dev_handle.close()

    def set_configuration(self, dev_handle: BoardPort, config_value: int) -> None:
        pass

    def get_configuration(self, dev_handle: BoardPort) -> int:
        return 1

    def set_interface_altsetting(self, dev_handle: BoardPort, intf: int, altsetting: int) -> None:
        pass

    def claim_interface(self, dev_handle: BoardPort, intf: int) -> None:
        if self.board.faults.unplugged:
            raise _no_device("claim_interface")

    def release_interface(self, dev_handle: BoardPort, intf: int) -> None:
        pass

    def clear_halt(self, dev_handle: BoardPort, ep: int) -> None:
        pass

    def is_kernel_driver_active(self, dev_handle: BoardPort, intf: int) -> bool:
        return False

    # --- bulk transfers --------------------------------------------------------------------
    def bulk_write(
        self, dev_handle: BoardPort, ep: int, intf: int, data: array.array[int], timeout: int
    ) -> int:
        try:
            return dev_handle.write(data.tobytes())
        except TransportClosedError:
            raise _no_device("bulk_write") from None

    def bulk_read(
        self, dev_handle: BoardPort, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        size = len(buff) * buff.itemsize
        try:
            data = dev_handle.read(size, (timeout or 1000) / 1000.0)
        except TransportClosedError:
            raise _no_device("bulk_read") from None
        if not data:
            raise usb.core.USBTimeoutError(
                "Operation timed out", error_code=-7, errno=errno.ETIMEDOUT
            )
        memoryview(buff).cast("B")[: len(data)] = data
        return len(data)
