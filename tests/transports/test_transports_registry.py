"""Transports by URL: pyserial handlers, spy dumps, sim:// devices, usb:// via pyusb."""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from firmware_protocol import NEED_DATA, Capabilities, Connection, Role, Version
from hil.errors import ConfigError
from hil.transports import (
    SpyTransport,
    TransportClosedError,
    TransportError,
    TransportOpenError,
    open_transport,
    split_url,
)
from hil.transports.serial_transport import open_serial
from hil.transports.spy import hexdump_lines
from sim_devices.board.usb_backend import SimulatedUsbBackend
from sim_devices.stage.clock import ManualClock


def handshake(transport: object) -> list[object]:
    host = Connection(Role.HOST)
    transport.write(host.send(host.make_hello()))  # type: ignore[attr-defined]
    events: list[object] = []
    for _ in range(200):
        data = transport.read(4096)  # type: ignore[attr-defined]
        if data:
            host.receive_data(data)
        while (event := host.next_event()) is not NEED_DATA:
            events.append(event)
        if len(events) >= 2:
            break
    return events


def test_loop_url_echoes_and_chunks_are_whole() -> None:
    t = open_transport("loop://", timeout=0.05)
    payload = bytes(range(256)) * 10
    t.write(payload)
    got = b""
    while len(got) < len(payload):
        got += t.read(1000)
    assert got == payload and t.read(10) == b""
    t.close()
    t.close()  # idempotent


def test_posix_port_reads_what_is_there_and_reports_a_hang_up() -> None:
    master, slave = os.openpty()
    t = open_serial(os.ttyname(slave), timeout=0.05)  # pyserial puts the port in raw mode
    try:
        assert t._posix_fd() is not None  # the select + read path, not pyserial's read
        assert t.read(100) == b""  # nothing sent: the timeout
        payload = bytes(range(1, 256)) * 40
        os.write(master, payload)
        got = b""
        while len(got) < len(payload):
            chunk = t.read(1 << 16)
            assert chunk, "the bytes written did not arrive"
            got += chunk
        assert got == payload
        os.close(master)
        with pytest.raises(TransportClosedError, match="link lost while reading"):
            for _ in range(3):
                t.read(10)
    finally:
        t.close()
        os.close(slave)
    assert open_transport("loop://")._posix_fd() is None  # type: ignore[attr-defined]


def test_socket_url_reaches_a_tcp_server() -> None:
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def echo_once() -> None:
        conn, _ = server.accept()
        conn.sendall(conn.recv(100).upper())
        conn.close()

    thread = threading.Thread(target=echo_once)
    thread.start()
    t = open_transport(f"socket://127.0.0.1:{port}", timeout=1.0)
    t.write(b"ping")
    got = b""
    while len(got) < 4:  # read() returns as soon as any bytes are there
        got += t.read(100)
    assert got == b"PING"
    t.close()
    thread.join()
    server.close()


@pytest.mark.parametrize("via", ["memory", "pty", "usb"])
def test_sim_board_answers_the_handshake(via: str) -> None:
    t = open_transport(f"sim://board?via={via}", clock=ManualClock())
    try:
        events = handshake(t)
        assert isinstance(events[0], Version) and isinstance(events[1], Capabilities)
        assert t.url == f"sim://board?via={via}"
    finally:
        t.close()


def test_sim_stage_is_a_port_grblstage_can_open() -> None:
    from hil.devices.grbl import GrblStage

    port: Any = open_transport("sim://stage")  # a serial-like port, not only a Transport
    try:
        with GrblStage(port) as stage:
            assert stage.settings is not None and stage.limits[1] == 0.0
    finally:
        port.close()


def test_sim_stage_in_memory_runs_on_the_injected_clock() -> None:
    from hil.devices.grbl import GrblStage
    from sim_devices.stage import GrblSimConfig

    clock = ManualClock(0.0)
    config = GrblSimConfig(homing=True, power_up_position_mm=-20.0)
    options = {"config": config}
    with GrblStage("sim://stage?via=memory", clock=clock, transport_options=options) as stage:
        assert stage.transport.url == "sim://stage?via=memory"
        homed = stage.make_ready()  # the simulated GRBL powers up locked
        assert homed.position == pytest.approx(-0.001) and clock.now() > 1.0


def test_spy_dumps_both_directions_with_hex_and_ascii(tmp_path: Path) -> None:
    log = tmp_path / "traffic.log"
    t = open_transport(f"spy://loop://?file={log}", timeout=0.05)
    assert isinstance(t, SpyTransport) and t.url == "spy://loop://"
    t.write(b"G0 X1\n\x00\xff")
    assert t.read(100) == b"G0 X1\n\x00\xff"
    t.close()
    lines = log.read_text().splitlines()
    assert [line.split()[1:3] for line in lines] == [["TX", "0000"], ["RX", "0000"]]
    assert lines[0].endswith(f"{'47 30 20 58 31 0a 00 ff':<48} G0 X1...")
    assert float(lines[0].split()[0]) >= 0.0


def test_spy_wraps_a_sim_board_and_keeps_its_options(tmp_path: Path) -> None:
    log = tmp_path / "board.log"
    t = open_transport(f"spy://sim://board?via=pty&delay=5&file={log}", clock=ManualClock())
    try:
        assert t.url == "spy://sim://board?delay=5&via=pty"
        assert isinstance(handshake(t)[0], Version)
    finally:
        t.close()
    text = log.read_text()
    assert " TX 0000  " in text and " RX 0000  " in text


def test_hexdump_lines_split_at_16_bytes() -> None:
    rows = hexdump_lines(bytes(range(20)))
    assert [r[0] for r in rows] == [0, 16] and rows[1][1] == "10 11 12 13"


def test_split_url_keeps_paths_and_options() -> None:
    assert split_url("usb://1209:ca50?interface=1") == ("usb", "1209:ca50", {"interface": "1"})
    assert split_url("COM3") == ("", "COM3", {})


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("ftp://x", "url = 'ftp://x' is not allowed: must be a device path or one of serial://"),
        ("usb://12:zz", "usb:// device = '12:zz' is not allowed: must be VID:PID in hex"),
        ("usb://1209:ca50?speed=hi", "usb:// option = 'speed' is not allowed: must be one of"),
        ("usb://1209:ca50?backend=winusb", "usb backend = 'winusb' is not allowed: must be one"),
        ("sim://tank", "sim:// device = 'tank' is not allowed: must be board or stage"),
        ("sim://board?via=can", "via = 'can' is not allowed: must be one of memory, pty, usb"),
        ("sim://board?delay=x", "delay = 'x' is not allowed: must be an integer"),
        ("sim://stage?via=usb", "via = 'usb' is not allowed: must be one of pty, memory"),
        ("sim://stage?speed=1", "sim://stage option = 'speed' is not allowed: must be via"),
        ("serial:///dev/null?baud=fast", "baud = 'fast' is not allowed: must be an integer"),
        ("serial:///dev/null?dtr=off", "serial:// option dtr = 'off' is not allowed: must be 0"),
        ("serial:///dev/null?parity=E", "serial:// option = 'parity' is not allowed: must be one"),
        ("", "url = '' is not allowed: must be a non-empty transport URL"),
    ],
)
def test_bad_urls_are_config_errors_naming_the_field(url: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        open_transport(url)


@pytest.mark.parametrize(
    ("query", "options", "levels"),
    [
        ("", {}, (True, True)),  # pyserial's default: both raised
        ("", {"dtr": False, "rts": False}, (False, False)),  # a driver's default
        ("?dtr=1", {"dtr": False, "rts": False}, (True, False)),  # the URL wins
        ("?dtr=0&rts=1", {}, (False, True)),
    ],
)
def test_serial_modem_lines_are_set_before_the_port_opens(
    query: str, options: dict[str, bool], levels: tuple[bool, bool]
) -> None:
    # A real pty pair: the port is opened by path through serial:// and as a plain path.
    controller, device = os.openpty()
    try:
        name = os.ttyname(device)
        for url in (f"serial://{name}{query}", *([name] if not query else [])):
            t: Any = open_transport(url, timeout=0.1, **options)
            try:
                assert (t.port.dtr, t.port.rts) == levels
                t.write(b"?")
                assert os.read(controller, 10) == b"?"
            finally:
                t.close()
    finally:
        os.close(controller)
        os.close(device)


def test_missing_serial_device_is_a_transport_open_error() -> None:
    with pytest.raises(TransportOpenError, match=r"cannot open '/dev/does-not-exist'.*dialout"):
        open_transport("/dev/does-not-exist")


def test_transport_errors_are_the_host_error_tree_s() -> None:
    from hil import errors

    assert TransportError is errors.TransportError
    assert issubclass(TransportOpenError, TransportError)
    assert issubclass(TransportClosedError, TransportError)


def test_usb_url_with_injected_backend_finds_the_board() -> None:
    backend = SimulatedUsbBackend()
    t = open_transport("usb://1209:CA50?interface=0", usb_backend=backend)
    try:
        assert isinstance(handshake(t)[1], Capabilities) and backend.opened == 1
    finally:
        t.close()


def test_usb_unplug_is_a_closed_link_and_the_device_vanishes() -> None:
    backend = SimulatedUsbBackend()
    t = open_transport("usb://1209:ca50", usb_backend=backend)
    backend.board.faults.disconnect()
    with pytest.raises(TransportClosedError, match="usb://1209:ca50: link lost while reading"):
        t.read(100)
    t.close()
    with pytest.raises(TransportOpenError, match="no USB device 1209:ca50 found"):
        open_transport("usb://1209:ca50", usb_backend=backend)


def test_real_libusb_backend_enumerates(require_system: Callable[[bool, str], None]) -> None:
    import usb.backend.libusb1
    import usb.core

    backend = usb.backend.libusb1.get_backend()
    require_system(
        backend is not None, "libusb-1.0 is not installed (apt-get install libusb-1.0-0)"
    )
    devices = list(usb.core.find(find_all=True, backend=backend))
    assert all(0 <= d.idVendor <= 0xFFFF and 0 <= d.idProduct <= 0xFFFF for d in devices)
    # ffff:fffe is reserved and never assigned: the real backend reports it missing.
    with pytest.raises(TransportOpenError, match="no USB device ffff:fffe found"):
        open_transport("usb://ffff:fffe?backend=libusb1")
