"""The watch page's HTTP server (stdlib ``http.server``, one thread per request).

Routes: ``/`` the page; ``/api/state``, ``/api/estimates?since=N``, ``/api/truth``,
``/api/map`` JSON from :class:`~hil.watch.api.WatchData`; ``/files/time_codeword_map.png``
the map ``hil tank-run`` saves beside the recording. A bad query is a 400 and a recording
that cannot be read (damaged, deleted while watched) a 503, each with ``{"error": "..."}``
so the page can say why. A browser that drops its connection (a tab closed mid-request) is
logged at debug level, never a traceback.
"""

from __future__ import annotations

import json
import logging
import sys
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from hil.errors import ConfigError
from hil.watch.api import MAP_PNG, WatchData

_LOG = logging.getLogger(__name__)


def page_html() -> bytes:
    """The watch page (``hil/watch/page.html``, package data)."""
    return resources.files("hil.watch").joinpath("page.html").read_bytes()


def _since(query: str) -> int:
    values = parse_qs(query).get("since", ["0"])
    try:
        return int(values[-1])
    except ValueError:
        raise ConfigError("since", values[-1], "an integer >= 0 (an estimate row number)") from None


#: A browser that closed its tab (or reloaded) mid-request: its connection is gone, which is
#: normal for a page that polls, so it is logged at debug level, not shown as a traceback.
_PEER_GONE = (BrokenPipeError, ConnectionResetError, ConnectionAbortedError)


def _peer_gone(client: Any, exc: BaseException) -> None:
    _LOG.debug("%s closed the connection: %s", client, exc)


class _Handler(BaseHTTPRequestHandler):
    server: WatchServer

    def log_message(self, format: str, *args: Any) -> None:
        _LOG.debug("%s - %s", self.address_string(), format % args)

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def handle(self) -> None:
        try:
            super().handle()
        except _PEER_GONE as exc:
            _peer_gone(self.client_address, exc)

    def _json(self, status: int, payload: dict[str, Any]) -> None:
        body = json.dumps(payload, allow_nan=False).encode()
        self._send(status, body, "application/json")

    def do_GET(self) -> None:
        url = urlsplit(self.path)
        data = self.server.data
        routes = {
            "/api/state": data.state,
            "/api/truth": data.truth,
            "/api/map": data.codeword_map,
        }
        try:
            if url.path in ("/", "/index.html"):
                self._send(HTTPStatus.OK, page_html(), "text/html; charset=utf-8")
            elif url.path in routes:
                self._json(HTTPStatus.OK, routes[url.path]())
            elif url.path == "/api/estimates":
                self._json(HTTPStatus.OK, data.estimates(_since(url.query)))
            elif url.path == f"/files/{MAP_PNG}" and (png := data.map_png()) is not None:
                self._send(HTTPStatus.OK, png, "image/png")
            else:
                self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page: {url.path}"})
        except ConfigError as exc:
            self._json(HTTPStatus.BAD_REQUEST, {"error": str(exc)})
        except _PEER_GONE:
            raise  # the browser went away: nobody to answer (handle() notes it)
        except (OSError, KeyError, ValueError, RuntimeError) as exc:
            _LOG.warning("reading %s: %s", data.path, exc)
            self._json(
                HTTPStatus.SERVICE_UNAVAILABLE,
                {"error": f"{data.path} cannot be read: {exc}"},
            )


class WatchServer(ThreadingHTTPServer):
    """Serves the watch page of one recording at ``host:port`` (port 0: a free one).

    Use :meth:`start` to serve on a background thread (tests, the CLI's browser) or
    ``serve_forever()``; :meth:`close` stops serving and closes the recording. With
    ``data.live_map`` a thread keeps the map up with the recording from the start.
    """

    daemon_threads = True

    def __init__(self, data: WatchData, host: str = "127.0.0.1", port: int = 0) -> None:
        self.data = data
        super().__init__((host, port), _Handler)
        self._thread: threading.Thread | None = None
        self._stop_map = threading.Event()
        self._map_thread: threading.Thread | None = None
        if data.live_map is not None:
            self._map_thread = threading.Thread(
                target=data.live_map.follow, args=(self._stop_map,), name="hil-watch-map",
                daemon=True,
            )  # fmt: skip
            self._map_thread.start()

    @property
    def url(self) -> str:
        """The page's address, ``http://host:port/``."""
        host, port = self.server_address[:2]
        name = host.decode() if isinstance(host, bytes) else str(host)
        if ":" in name:
            name = f"[{name}]"
        return f"http://{name}:{port}/"

    def start(self) -> WatchServer:
        """Serve on a daemon thread; returns self."""
        self._thread = threading.Thread(target=self.serve_forever, name="hil-watch", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop serving (if started) and the map's updates, close the socket and the
        recording."""
        if self._thread is not None:
            self.shutdown()
            self._thread.join()
            self._thread = None
        self._stop_map.set()
        if self._map_thread is not None:
            self._map_thread.join()
            self._map_thread = None
        self.server_close()
        self.data.close()

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A connection the browser dropped is noted at debug level; anything else is
        reported as ``socketserver`` does (a traceback on stderr)."""
        exc = sys.exc_info()[1]
        if isinstance(exc, _PEER_GONE):
            _peer_gone(client_address, exc)
            return
        super().handle_error(request, client_address)

    def __enter__(self) -> WatchServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
