"""A browser that goes away mid-request (a tab closed while a poll is in flight) leaves no
traceback in the server's output: the dropped connection is logged at debug level."""

from __future__ import annotations

import logging
import socket

import numpy as np
import pytest

from hil.watch import WatchData, WatchServer


def _request_then_hang_up(server: WatchServer, path: str) -> None:
    """Serve one request on a socket pair whose browser end has sent ``path`` and closed:
    the server reads the request, and its answer finds the connection gone (EPIPE)."""
    browser, served = socket.socketpair()
    browser.sendall(f"GET {path} HTTP/1.1\r\nHost: test\r\n\r\n".encode())
    browser.close()
    # What the server's thread does with each connection, here in the test's thread.
    server.process_request_thread(served, ("browser", 0))


@pytest.mark.parametrize("path", ["/", "/api/state", "/api/estimates?since=0", "/api/nothing"])
def test_a_closed_tab_leaves_no_traceback(
    recorder: object,
    path: str,
    capfd: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    rec = recorder
    rec.writer.append_samples(rec.origin, np.zeros(1000, np.int16))  # type: ignore[attr-defined]
    rec.writer.flush()  # type: ignore[attr-defined]
    caplog.set_level(logging.DEBUG, logger="hil.watch.server")
    with WatchServer(WatchData.open(rec.path)) as server:  # type: ignore[attr-defined]
        _request_then_hang_up(server, path)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "BrokenPipe" not in err and err == ""
    assert any("closed the connection" in r.getMessage() for r in caplog.records)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_another_server_error_is_still_reported(
    recorder: object, capfd: pytest.CaptureFixture[str]
) -> None:
    """Only a dropped connection is quiet: a fault of the server itself keeps its traceback."""
    with WatchServer(WatchData.open(recorder.path)) as server:  # type: ignore[attr-defined]
        try:
            raise ValueError("a fault of the server")
        except ValueError:
            server.handle_error(None, ("browser", 0))
    assert "ValueError: a fault of the server" in capfd.readouterr().err
