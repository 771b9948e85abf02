"""Open a transport from a URL: one registry for every way of reaching a device.

==========================================  ================================================
URL                                         transport
==========================================  ================================================
``/dev/ttyACM0``, ``COM3``                  serial port (pyserial), default baud 115200
``serial:///dev/ttyACM0?baud=921600``       the same, with options: ``baud``; ``dtr``,
                                            ``rts`` (``0``/``1``: the modem lines once open)
``loop://``, ``socket://host:port``         pyserial's own URL handlers
``usb://1209:ca50?interface=0``             bulk endpoints via pyusb (libusb-1.0);
                                            ``?backend=libusb1|libusb0|openusb`` or the
                                            ``usb_backend=`` keyword (a backend object)
``sim://board?via=memory|pty|usb``          a simulated board started now (:mod:`.sim`)
``sim://board?impl=c``                      the C reference firmware on a pty (:mod:`.sim`)
``sim://stage?via=pty|memory``              the simulated GRBL stage on a pty, or in the
                                            reader's thread
``hwgrep://REGEXP[&n=N][&baud=B]``          the N-th serial port (0-based) whose name,
                                            description or hardware id (USB VID:PID, serial
                                            number) matches REGEXP (pyserial's hwgrep;
                                            ``hil devices`` lists them)
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
serial://, loop://, socket://, rfc2217://, usb://, sim://, hwgrep://, spy://; see \
hil.transports.registry
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import Any
from urllib.parse import parse_qsl

from hil.errors import ConfigError
from hil.transports.base import Transport
from hil.transports.serial_transport import open_serial
from hil.transports.spy import SpyTransport

#: Transports opened, with what a URL resolved to, at DEBUG (a run's run.log).
_LOG = logging.getLogger(__name__)

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


def _line_option(query: dict[str, str], options: dict[str, Any], name: str) -> bool | None:
    """A modem line's level from the URL (``?dtr=0``) or else the caller's default
    (``dtr=False`` keyword; ``None``: pyserial's default, raised)."""
    raw = query.get(name)
    if raw is None:
        default = options.get(name)
        return None if default is None else bool(default)
    if raw not in ("0", "1"):
        raise ConfigError(
            f"serial:// option {name}", raw, "0 (line low) or 1 (line raised)", f"e.g. ?{name}=0"
        )
    return raw == "1"


def _open_serial(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    _check_keys("serial", query, ("baud", "dtr", "rts"))
    try:
        baud = int(query.get("baud", "115200"))
    except ValueError:
        raise ConfigError(
            "baud", query["baud"], "an integer (bit/s)", "e.g. ?baud=115200"
        ) from None
    return open_serial(
        rest,
        baudrate=baud,
        timeout=timeout,
        dtr=_line_option(query, options, "dtr"),
        rts=_line_option(query, options, "rts"),
    )


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


SIM_DEVICES = ("board", "stage")


def check_url(url: str, field: str = "url", sim_device: str | None = None) -> None:
    """Refuse ``url`` as the setting ``field`` when no opener could open it, without opening.

    ``sim_device``: the simulated device the setting must name when the URL is ``sim://``.

    >>> check_url("sim://bord", "devices.board", "board")
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: devices.board = 'sim://bord' is not allowed: must be sim://board \
(a simulated board); did you mean sim://board?
    """
    if not isinstance(url, str) or not url:
        raise ConfigError(field, url, "a non-empty transport URL or device path")
    scheme, rest, _ = split_url(url[len("spy://") :] if url.startswith("spy://") else url)
    if scheme and scheme not in _OPENERS and scheme != "hwgrep":
        known = ", ".join(f"{s}://" for s in (*_OPENERS, "hwgrep", "spy"))
        raise ConfigError(field, url, f"a device path or one of {known}")
    if scheme != "sim":
        return
    wanted = (sim_device,) if sim_device else SIM_DEVICES
    if rest not in wanted:
        import difflib

        close = difflib.get_close_matches(rest, SIM_DEVICES, n=1)
        hint = f"did you mean sim://{close[0]}?" if close else "see hil.transports.registry"
        what = f" (a simulated {sim_device})" if sim_device else ""
        raise ConfigError(field, url, " or ".join(f"sim://{w}" for w in wanted) + what, hint)


def _open_sim(rest: str, query: dict[str, str], options: dict[str, Any], timeout: float) -> Any:
    from hil.transports.sim import open_sim_board, open_sim_stage

    if rest == "board":
        _check_keys("sim://board", query, ("via", "delay", "gain", "impl"))
        return open_sim_board(query, options, timeout)
    if rest == "stage":
        return open_sim_stage(query, options, timeout)
    raise ConfigError("sim:// device", rest, "board or stage", "e.g. sim://board?via=pty")


def resolve_hwgrep(url: str) -> tuple[str, int]:
    """The serial device and baud rate ``hwgrep://REGEXP[&n=N][&baud=B]`` names.

    The regexp is matched (case-insensitive) against every port's name, description and
    hardware id by pyserial's ``list_ports.grep``, in sorted order of the device names.
    """
    from serial.tools import list_ports

    body = url[len("hwgrep://") :]
    regexp, *options = body.split("&")
    settings = {"n": "0", "baud": "115200"}
    for option in options:
        key, _, value = option.partition("=")
        if key not in settings:
            raise ConfigError("hwgrep:// option", key, "n=N or baud=B", "e.g. hwgrep://2341:&n=0")
        settings[key] = value
    try:
        index, baud = int(settings["n"]), int(settings["baud"])
    except ValueError:
        raise ConfigError("hwgrep:// option", body, "integers in n=N and baud=B") from None
    if not regexp:
        raise ConfigError("url", url, "hwgrep://REGEXP", "e.g. hwgrep://USB VID:PID=2341")
    ports = sorted(list_ports.grep(regexp), key=lambda p: p.device)
    if index >= len(ports) or index < 0:
        listed = ", ".join(f"{p.device} ({p.hwid})" for p in list_ports.comports()) or "none"
        raise ConfigError(
            "url", url, f"a regexp matching at least {index + 1} serial port(s); "
            f"{len(ports)} match", f"ports on this machine: {listed}; see hil devices",
        )  # fmt: skip
    return str(ports[index].device), baud


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
    ``world=``, ``spec=``, ``faults=`` for ``sim://``; ``dtr=``, ``rts=`` for serial ports
    and plain device paths: the level the line is set to before the port opens, unless the
    URL gives ``?dtr=``/``?rts=``; default pyserial's, raised).
    """
    if not isinstance(url, str) or not url:
        raise ConfigError("url", url, "a non-empty transport URL or device path")
    opened = _open(url, timeout, options)
    _LOG.debug("transport %s opened (%s)", url, type(opened).__name__)
    return opened


def _open(url: str, timeout: float, options: dict[str, Any]) -> Transport:
    if url.startswith("spy://"):
        transport: Transport = _open_spy(url, options, timeout)
        return transport
    if url.startswith("hwgrep://"):
        device, baud = resolve_hwgrep(url)
        _LOG.debug("transport %s resolved to %s at %d baud", url, device, baud)
        return open_serial(device, baudrate=baud, timeout=timeout)
    scheme, rest, query = split_url(url)
    if scheme == "":
        plain: Transport = _open_serial(url, {}, options, timeout)
        return plain
    opener = _OPENERS.get(scheme)
    if opener is None:
        known = ", ".join(f"{s}://" for s in (*_OPENERS, "hwgrep", "spy"))
        raise ConfigError(
            "url", url, f"a device path or one of {known}", "see hil.transports.registry"
        )
    opened: Transport = opener(rest, query, options, timeout)
    return opened
