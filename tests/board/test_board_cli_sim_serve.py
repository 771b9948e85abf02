"""``hil sim-serve board|stage`` prints a pty path that another program can open."""

from __future__ import annotations

import io
import threading
from contextlib import redirect_stdout

import pytest
import serial

from firmware_protocol import NEED_DATA, Connection, Role, Version
from hil.cli.main import build_parser, main


def _serve(device: str) -> tuple[threading.Thread, threading.Event, io.StringIO, list[int]]:
    from hil.cli import sim_serve

    args = build_parser().parse_args(["sim-serve", device])
    stop, out, status = threading.Event(), io.StringIO(), []

    def run() -> None:
        with redirect_stdout(out):
            status.append(sim_serve.run(args, stop))

    thread = threading.Thread(target=run)
    thread.start()
    return thread, stop, out, status


def _port_name(out: io.StringIO) -> str:
    for _ in range(2000):
        if out.getvalue().endswith("\n"):
            return out.getvalue().strip()
        threading.Event().wait(0.001)
    raise AssertionError("sim-serve printed no port")


def test_sim_serve_board_prints_a_port_speaking_the_protocol() -> None:
    thread, stop, out, status = _serve("board")
    try:
        port = serial.serial_for_url(_port_name(out), timeout=2)
        host = Connection(Role.HOST)
        port.write(host.send(host.make_hello()))
        host.receive_data(port.read_until(b"\x00"))
        event = host.next_event()
        assert isinstance(event, Version) and host.next_event() is NEED_DATA
        port.close()
    finally:
        stop.set()
        thread.join()
    assert status == [0]


def test_sim_serve_stage_prints_a_grbl_port() -> None:
    thread, stop, out, status = _serve("stage")
    try:
        port = serial.serial_for_url(_port_name(out), timeout=2)
        port.write(b"$I\n")
        assert port.read_until(b"ok\r\n").endswith(b"ok\r\n")
        port.close()
    finally:
        stop.set()
        thread.join()
    assert status == [0]


def test_sim_serve_rejects_a_negative_delay(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim-serve", "board", "--delay", "-3"]) == 2
    assert "--delay = -3 is not allowed: must be >= 0 samples" in capsys.readouterr().err
