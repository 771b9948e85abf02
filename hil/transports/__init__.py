"""Transports by URL: serial ports, USB bulk, sockets, simulated devices, traffic spies.

``open_transport(url)`` returns an object with the :class:`Transport` contract
(:mod:`.base`); drivers accept a URL or such an object. See :mod:`.registry` for the URLs.
"""

from hil.transports.base import (
    IdentifiedTransport,
    QuietTransport,
    Transport,
    TransportClosedError,
    TransportError,
    TransportOpenError,
    TransportTimeoutError,
)
from hil.transports.registry import open_transport, register_scheme, split_url
from hil.transports.serial_transport import SerialTransport, open_serial
from hil.transports.spy import SpyTransport

__all__ = [
    "IdentifiedTransport",
    "QuietTransport",
    "SerialTransport",
    "SpyTransport",
    "Transport",
    "TransportClosedError",
    "TransportError",
    "TransportOpenError",
    "TransportTimeoutError",
    "open_serial",
    "open_transport",
    "register_scheme",
    "split_url",
]
