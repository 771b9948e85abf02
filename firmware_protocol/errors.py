"""Error classes of the wire protocol, split by who broke the rule (as in h11).

- :class:`LocalProtocolError`: this side tried something illegal (a send in the wrong state,
  a field value out of range, more DAC samples than the credit allows). Nothing was encoded.
- :class:`RemoteProtocolError`: the peer sent a well-formed frame (its CRC is good) whose
  content breaks the protocol (a message illegal in the current state, a field out of range,
  an incompatible version). Line noise is *not* an error: the reader resyncs and emits a
  :class:`~firmware_protocol.events.FrameError` event instead.

This package does no I/O: the errors of the links that move the bytes (``TransportError``
and its kinds) belong to the host, in :mod:`hil.errors`. Their old names here still resolve,
with a DeprecationWarning, for code written when they were defined in this module.
"""

from __future__ import annotations

import warnings
from typing import Any

#: Names that moved to :mod:`hil.errors` (the I/O side).
MOVED_TO_HOST = ("TransportError", "TransportTimeoutError", "TransportClosedError")


class ProtocolError(Exception):
    """Base class of the protocol rule violations (local and remote)."""


class LocalProtocolError(ProtocolError):
    """This side tried to do something the protocol does not allow; nothing was sent."""


class RemoteProtocolError(ProtocolError):
    """The peer sent an intact frame whose content breaks the protocol."""


class RefusedFrame(RemoteProtocolError):
    """An intact host frame the device must refuse with NAK ``code`` (SPEC section 2.2).

    ``ref_seq`` and ``ref_type`` are the refused frame's seq and message type, quoted by the
    NAK. ``code`` is a :class:`~firmware_protocol.enums.NakCode` value: BAD_STATE (not legal in
    this state), BAD_PAYLOAD (short payload, value out of range, data that does not match the
    configuration) or CREDIT_EXCEEDED.
    """

    def __init__(self, message: str, *, code: int, ref_seq: int, ref_type: int) -> None:
        super().__init__(message)
        self.code = code
        self.ref_seq = ref_seq
        self.ref_type = ref_type


class FieldValueError(LocalProtocolError, ValueError):
    """A message field value is out of its allowed range; raised before anything is encoded.

    The message has the same shape as the host's configuration errors.

    Examples
    --------
    >>> str(FieldValueError("Configure.sample_rate_hz", 0, "1 .. 100000000 Hz", "set a rate"))
    'Configure.sample_rate_hz = 0 is not allowed: must be 1 .. 100000000 Hz; set a rate'
    """

    def __init__(self, field: str, value: Any, allowed: str, hint: str = "") -> None:
        self.field = field
        self.value = value
        self.allowed = allowed
        self.hint = hint
        message = f"{field} = {value!r} is not allowed: must be {allowed}"
        if hint:
            message += f"; {hint}"
        super().__init__(message)


class IncompatiblePeerError(RemoteProtocolError):
    """The peer speaks another protocol major version or was built from other definitions.

    Attributes hold both sides' values so a driver can report them: ``local_version`` and
    ``peer_version`` are ``(major, minor)``; ``local_schema`` and ``peer_schema`` are the
    32-bit schema hashes.
    """

    def __init__(
        self,
        message: str,
        *,
        local_version: tuple[int, int],
        peer_version: tuple[int, int],
        local_schema: int,
        peer_schema: int,
    ) -> None:
        super().__init__(message)
        self.local_version = local_version
        self.peer_version = peer_version
        self.local_schema = local_schema
        self.peer_schema = peer_schema


def __getattr__(name: str) -> Any:
    """The moved transport errors, from the host package (see the module docstring)."""
    if name not in MOVED_TO_HOST:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    warnings.warn(
        f"firmware_protocol.{name} moved to hil.errors.{name}: import it from there",
        DeprecationWarning,
        stacklevel=2,
    )
    from hil import errors  # the one allowed host import: these names live there now

    return getattr(errors, name)
