"""What the board driver logs at DEBUG (into a run's ``run.log``): every control frame sent
and received (not the sample frames DAC_DATA and ADC_DATA: thousands a second), every change
of the session state, link losses, reconnect attempts and timeouts.

The logger is ``hil.devices.board``'s (:data:`LOG`); every message names the board's URL.
Frames are formatted only when DEBUG is on, so a run at the default level pays nothing.

>>> from firmware_protocol import Keepalive
>>> frame_text(Keepalive(1000))
"KEEPALIVE {'watchdog_timeout_ms': 1000}"
"""

from __future__ import annotations

import logging

from firmware_protocol import AdcData, DacData, Message, State

#: The board driver's logger (``hil.devices.board``).
LOG = logging.getLogger("hil.devices.board")

_SAMPLE_FRAMES = (AdcData, DacData)


def frame_text(message: Message) -> str:
    """``NAME {field: value, ...}`` of a frame (a NAK with its detail text)."""
    return f"{message.NAME} {message.field_values()}"


def log_frame(url: str, direction: str, message: object) -> None:
    """A control frame (or a reader event: frame error, sequence gap, unknown type) sent
    (``direction`` ``"->"``) or received (``"<-"``); sample frames are not logged."""
    if isinstance(message, _SAMPLE_FRAMES) or not LOG.isEnabledFor(logging.DEBUG):
        return
    text = frame_text(message) if isinstance(message, Message) else repr(message)
    LOG.debug("board %s %s %s", url, direction, text)


def log_state(url: str, before: State, after: State) -> None:
    """The session state changed."""
    if before is not after:
        LOG.debug("board %s: state %s -> %s", url, before.name, after.name)
