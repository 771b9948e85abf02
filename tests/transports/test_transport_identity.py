"""What each transport says it resolved to, for the run's record of what was connected
(:func:`hil.transports.identity.port_identity`): a serial port its path, a spy its inner
transport's, a USB device its descriptor, a link in memory nothing."""

from __future__ import annotations

import io
import os
import pty
from collections.abc import Iterator

import pytest

from hil.transports import IdentifiedTransport, QuietTransport, SpyTransport, open_serial
from hil.transports.identity import port_identity, usb_descriptor_identity
from hil.transports.serial_transport import SerialTransport


@pytest.fixture
def pty_path() -> Iterator[str]:
    controller, follower = pty.openpty()
    try:
        yield os.ttyname(follower)
    finally:
        os.close(follower)
        os.close(controller)


def test_a_serial_port_on_a_pty_is_its_path_without_usb_ids(pty_path: str) -> None:
    transport = open_serial(pty_path, timeout=0.01)
    try:
        assert isinstance(transport, SerialTransport) and isinstance(transport, IdentifiedTransport)
        assert port_identity(transport) == {"port": pty_path}
    finally:
        transport.close()


def test_a_spy_says_what_its_inner_transport_resolved_to(pty_path: str) -> None:
    spy = SpyTransport(open_serial(pty_path, timeout=0.01), io.StringIO())
    try:
        assert port_identity(spy) == {"port": pty_path}
    finally:
        spy.close()


def test_a_pyserial_url_is_named_as_opened() -> None:
    transport = open_serial("loop://", timeout=0.01)
    try:
        assert port_identity(transport) == {"port": "loop://"}
    finally:
        transport.close()


def test_a_link_in_memory_tells_nothing() -> None:
    from sim_devices.board.core import SimulatedBoard
    from sim_devices.board.port import BoardPort, MemoryBoardLink

    link = MemoryBoardLink(BoardPort(SimulatedBoard()), url="sim://board")
    try:
        assert not isinstance(link, IdentifiedTransport) and isinstance(link, QuietTransport)
        assert port_identity(link) == {}
    finally:
        link.close()


class _Descriptor:
    """A pyusb device's descriptor as pyusb shows it: the ids, and string descriptors that
    raise where the device does not answer (no permission, none defined)."""

    idVendor = 0x1209
    idProduct = 0xCA50
    serial_number = "CAS0042"
    product = "CAS board"

    @property
    def manufacturer(self) -> str:
        raise ValueError("The device has no langid")


def test_a_usb_device_is_its_ids_and_the_strings_it_answers() -> None:
    assert usb_descriptor_identity(_Descriptor()) == {
        "usb_vid_pid": "1209:ca50",
        "usb_serial": "CAS0042",
        "product": "CAS board",
    }
