"""Open a transport from a URL: one registry for every way of reaching a device.

==========================================  ================================================
URL                                         transport
==========================================  ================================================
``/dev/ttyACM0``, ``COM3``                  serial port (pyserial), default baud 115200
``serial:///dev/ttyACM0?baud=921600``       the same, with options
``loop://``, ``socket://host:port``         pyserial's own URL handlers
``usb://1209:ca50?interface=0``             bulk endpoints via pyusb (libusb-1.0);
                                            ``?backend=libusb1|libusb0|openusb`` or the
                                            ``usb_backend=`` keyword (a backend object)
``sim://board?via=memory|pty|usb``          a simulated board started now (:mod:`.sim`)
``sim://board?impl=c``                     the C reference firmware on a pty (:mod:`.sim`)
``sim://stage``                             the simulated GRBL stage on a pty
``spy://<inner-url>?file=traffic.log``      any of the above, traffic dumped to a file
==========================================  ================================================

>>> t = open_transport("loop://", timeout=0.1)
>>> t.write(b"abc"), t.read(10)
(3, b'abc')
>>> t.close()
>>> open_transport("ftp://x")
Traceback (most recent call last):
...
hil.errors.ConfigError: url = 'ftp://x' is not allowed: must be a device path or one of \
serial://, loop://, socket://, rfc2217://, usb://, sim://, spy://; see hil.transports.registry
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qsl

from hil.errors import ConfigError
from hil.transports.base import Transport
from hil.transports.serial_transport import open_serial
from hil.transports.spy import SpyTransport

Opener = Callable[[str, dict[str, str], dict[str, Any], float], Any]
"""``opener(rest, query, options, timeout)``: ``rest`` is the URL after ``scheme://`` and
before ``?``; ``query`` its options; ``options`` the keyword arguments of open_transport."""

_OPENERS: dict[str, Opener] = {}


def register_scheme(scheme: str, opener: Opener) -> None:
    """Make ``scheme://...`` URLs open through ``opener`` (replaces an earlier one)."""
    _OPENERS[scheme] = opener


def split_url(url: str) -> tuple[str, str, dict[str, str]]:
    """``(scheme, rest, query)``; a plain device path has scheme ``""``.

    >>> split_url("serial:///dev/ttyACM0?baud=921600")
    ('serial', '/dev/ttyACM0', {'baud': '921600'})
    >>> split_url("/dev/pts/3")
    ('', '/dev/pts/3', {})
    """
    if "://" not in url:
        return "", url, {}
    scheme, rest = url.split("://", 1)
    path, _, query = rest.partition("?")
    return scheme, path, dict(parse_qsl(query, keep_blank_values=True))


def _check_keys(scheme: str, query: dict[str, str], allowed: tuple[str, ...]) -> None:
    extra = sorted(set(query) - set(allowed))
    if extra:
        raise ConfigError(
            f"{scheme}:// option", extra[0], f"one of {', '.join(allowed) or '(none)'}"
        )


def _open_serial(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    _check_keys("serial", query, ("baud",))
    try:
        baud = int(query.get("baud", "115200"))
    except ValueError:
        raise ConfigError(
            "baud", query["baud"], "an integer (bit/s)", "e.g. ?baud=115200"
        ) from None
    return open_serial(rest, baudrate=baud, timeout=timeout)


def _open_pyserial_url(scheme: str) -> Opener:
    def opener(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
        suffix = "?" + "&".join(f"{k}={v}" for k, v in query.items()) if query else ""
        return open_serial(f"{scheme}://{rest}{suffix}", timeout=timeout)

    return opener


def _open_usb(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    from hil.transports.usb_transport import UsbTransport, named_backend

    _check_keys("usb", query, ("interface", "backend"))
    try:
        vid_text, pid_text = rest.split(":")
        vid, pid = int(vid_text, 16), int(pid_text, 16)
        if not (0 <= vid <= 0xFFFF and 0 <= pid <= 0xFFFF):
            raise ValueError
    except ValueError:
        raise ConfigError(
            "usb:// device", rest, "VID:PID in hex, 4 digits each", "e.g. usb://1209:ca50"
        ) from None
    try:
        interface = int(query.get("interface", "0"))
    except ValueError:
        raise ConfigError("interface", query["interface"], "an integer >= 0") from None
    backend = options.get("usb_backend")
    if backend is None and "backend" in query:
        backend = named_backend(query["backend"])
    return UsbTransport(
        vid, pid, interface=interface, backend=backend, timeout=timeout, url=f"usb://{rest}"
    )


def _open_sim(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    from hil.transports.sim import open_sim_board, open_sim_stage

    if rest == "board":
        _check_keys("sim://board", query, ("via", "delay", "gain", "impl"))
        return open_sim_board(query, options, timeout)
    if rest == "stage":
        return open_sim_stage(query, options, timeout)
    raise ConfigError("sim:// device", rest, "board or stage", "e.g. sim://board?via=pty")


def _open_spy(url: str, options: dict[str, Any], timeout: float) -> Any:
    inner = url[len("spy://") :]
    path, _, query = inner.rpartition("?") if "?" in inner else (inner, "", "")
    params = dict(parse_qsl(query, keep_blank_values=True))
    target = params.pop("file", None)
    rest = "&".join(f"{k}={v}" for k, v in params.items())
    inner_url = f"{path}?{rest}" if rest else path
    if not inner_url:
        raise ConfigError("spy:// inner url", inner_url, "a transport URL", "spy://loop://")
    transport = open_transport(inner_url, timeout=timeout, **options)
    if target is None or target == "-":
        return SpyTransport(transport, sys.stderr)
    try:
        log = open(target, "a", encoding="utf-8")  # noqa: SIM115 (owned by the spy)
    except OSError as error:
        transport.close()
        raise ConfigError("spy file", target, "a writable path", str(error)) from None
    return SpyTransport(transport, log, owns_log=True)


register_scheme("serial", _open_serial)
for _scheme in ("loop", "socket", "rfc2217"):
    register_scheme(_scheme, _open_pyserial_url(_scheme))
register_scheme("usb", _open_usb)
register_scheme("sim", _open_sim)


def open_transport(url: str, *, timeout: float = 0.05, **options: Any) -> Transport:
    """Open ``url`` (table in the module docstring); ``timeout`` is the read wait, s.

    Keyword ``options`` go to the scheme's opener (``usb_backend=``; ``clock=``,
    ``world=``, ``spec=``, ``faults=`` for ``sim://``).
    """
    if not isinstance(url, str) or not url:
        raise ConfigError("url", url, "a non-empty transport URL or device path")
    if url.startswith("spy://"):
        transport: Transport = _open_spy(url, options, timeout)
        return transport
    scheme, rest, query = split_url(url)
    if scheme == "":
        return open_serial(url, timeout=timeout)
    opener = _OPENERS.get(scheme)
    if opener is None:
        known = ", ".join(f"{s}://" for s in (*_OPENERS, "spy"))
        raise ConfigError(
            "url", url, f"a device path or one of {known}", "see hil.transports.registry"
        )
    opened: Transport = opener(rest, query, options, timeout)
    return opened
