"""The session state machine: every legal transition of both roles, in one table.

Both ends track the same session state, each from its own side: a HOST that sends CONFIGURE
and the DEVICE that receives it both move READY -> CONFIGURING. A row says: in these states,
when this sender emits this kind of message, the session moves to this state (or stays).
``send`` checks the row with the local role as sender (a missing row raises
``LocalProtocolError``); ``next_event`` checks it with the peer as sender (a missing row
raises ``RemoteProtocolError``).

Message kinds are message names, refined for replies and alarms: ``ACK:CONFIGURE``,
``NAK:START``, ... for the answer to a command the receiver accepted in its state (the
command awaiting a reply, quoted by its seq), ``ACK:OTHER``/``NAK:OTHER`` for replies to
anything else (a NAK UNKNOWN_MESSAGE, a NAK BAD_STATE refusing a command that was illegal in
the device's state, a NAK of DAC data), ``STATUS:WATCHDOG`` for a STATUS with the
WATCHDOG_EXPIRED alarm, and ``CLOSE`` for :class:`~firmware_protocol.events.ConnectionClosed`.
"""

from __future__ import annotations

from enum import Enum

from firmware_protocol.enums import Alarm, Role
from firmware_protocol.messages import Ack, Configure, Message, Nak, Start, Status, Stop


class State(Enum):
    """Session states (the same names on both ends)."""

    IDLE = "IDLE"
    """Nothing exchanged yet."""
    HELLO_SENT = "HELLO_SENT"
    """The host sent HELLO; the device owes VERSION."""
    VERSION_SENT = "VERSION_SENT"
    """The device sent VERSION (and the versions are compatible); CAPABILITIES follows."""
    READY = "READY"
    """Handshake done; not configured."""
    CONFIGURING = "CONFIGURING"
    """CONFIGURE sent; waiting for its ACK (-> CONFIGURED) or NAK (-> READY)."""
    CONFIGURED = "CONFIGURED"
    """Configured, not streaming; DAC data may be preloaded against credit."""
    STARTING = "STARTING"
    """START sent; waiting for its ACK (-> STREAMING) or NAK (-> CONFIGURED)."""
    STREAMING = "STREAMING"
    """DAC data flows to the device and ADC data to the host."""
    STOPPING = "STOPPING"
    """STOP sent; ADC data in flight may still arrive; waiting for its ACK."""
    STOPPED = "STOPPED"
    """Stopped (by ACK of STOP or by the watchdog); may be configured or started again."""
    CLOSED = "CLOSED"
    """The session is over (stream ended, closed locally, or the peer was refused)."""


S = State
HOST, DEVICE = Role.HOST, Role.DEVICE
_SESSION = (
    S.READY,
    S.CONFIGURING,
    S.CONFIGURED,
    S.STARTING,
    S.STREAMING,
    S.STOPPING,
    S.STOPPED,
)
_ALL_OPEN = (S.IDLE, S.HELLO_SENT, S.VERSION_SENT, *_SESSION)
_DATA = (S.CONFIGURED, S.STARTING, S.STREAMING, S.STOPPED)
STAY = None

# (states it is legal in, sender, kind, next state or STAY)
_ROWS: tuple[tuple[tuple[State, ...], Role, str, State | None], ...] = (
    # handshake; a HELLO in a session starts a new one (reconnect on a UART, SPEC 2.6)
    ((S.IDLE, *_SESSION), HOST, "HELLO", S.HELLO_SENT),
    ((S.HELLO_SENT,), DEVICE, "VERSION", S.VERSION_SENT),
    ((S.VERSION_SENT,), DEVICE, "CAPABILITIES", S.READY),
    # configuration (a NAK leaves the device unconfigured)
    ((S.READY, S.CONFIGURED, S.STOPPED), HOST, "CONFIGURE", S.CONFIGURING),
    ((S.CONFIGURING,), DEVICE, "ACK:CONFIGURE", S.CONFIGURED),
    ((S.CONFIGURING,), DEVICE, "NAK:CONFIGURE", S.READY),
    # start and stop; STOP is accepted whenever something could be running
    ((S.CONFIGURED, S.STOPPED), HOST, "START", S.STARTING),
    ((S.STARTING,), DEVICE, "ACK:START", S.STREAMING),
    ((S.STARTING,), DEVICE, "NAK:START", S.CONFIGURED),
    ((S.STOPPING,), DEVICE, "ACK:START", STAY),  # START answered after STOP was sent
    ((S.STOPPING,), DEVICE, "NAK:START", STAY),
    ((S.CONFIGURED, S.STARTING, S.STREAMING, S.STOPPED), HOST, "STOP", S.STOPPING),
    ((S.STOPPING,), DEVICE, "ACK:STOP", S.STOPPED),
    # sample data under credit-based flow control
    (_DATA, HOST, "DAC_DATA", STAY),
    ((*_DATA, S.STOPPING), DEVICE, "CREDIT", STAY),
    ((S.STREAMING, S.STOPPING), DEVICE, "ADC_DATA", STAY),
    # monitoring, liveness and replies to anything else
    (_SESSION, HOST, "KEEPALIVE", STAY),
    (_SESSION, DEVICE, "SYNC", STAY),
    (_SESSION, DEVICE, "STATUS", STAY),
    ((S.STREAMING,), DEVICE, "STATUS:WATCHDOG", S.STOPPED),
    (tuple(s for s in _SESSION if s is not S.STREAMING), DEVICE, "STATUS:WATCHDOG", STAY),
    (_ALL_OPEN, DEVICE, "LOG", STAY),
    (_SESSION, DEVICE, "NAK:OTHER", STAY),
    # either side may end the session at any time
    ((*_ALL_OPEN, S.CLOSED), HOST, "CLOSE", S.CLOSED),
    ((*_ALL_OPEN, S.CLOSED), DEVICE, "CLOSE", S.CLOSED),
)

TRANSITIONS: dict[tuple[State, Role, str], State] = {
    (state, sender, kind): (state if target is STAY else target)
    for states, sender, kind, target in _ROWS
    for state in states
}
"""(state, sender, kind) -> next state, for every legal transition of both roles."""

COMMAND_NAMES = {cls.TYPE_ID: cls.NAME for cls in (Configure, Start, Stop)}
"""Commands that the device answers with ACK or NAK, by type id."""

_HINTS = {
    "CONFIGURE": "finish the handshake (HELLO, then wait for VERSION and CAPABILITIES)"
    " and wait for the ACK of any earlier command",
    "START": "send CONFIGURE and wait for its ACK first",
    "STOP": "nothing is running before CONFIGURE is acknowledged",
    "DAC_DATA": "configure first; DAC data is accepted from CONFIGURED until STOP",
    "KEEPALIVE": "finish the handshake first",
    "HELLO": "wait for VERSION and CAPABILITIES before starting the session over",
}


def message_kind(message: Message, pending: dict[int, int] | None = None) -> str:
    """The kind under which a message is looked up in :data:`TRANSITIONS`.

    ``pending`` maps a command type id to the seq of that command awaiting its reply; with
    it, a NAK that quotes anything else is ``NAK:OTHER`` (a refusal that moves no state).

    >>> from firmware_protocol.messages import Ack, Configure, Status
    >>> message_kind(Ack(ref_seq=4, ref_type=Configure.TYPE_ID))
    'ACK:CONFIGURE'
    >>> message_kind(Status(0, 0, 0, 0, 0, 2500, Alarm.WATCHDOG_EXPIRED))
    'STATUS:WATCHDOG'
    """
    if isinstance(message, Ack | Nak):
        answers = pending is None or pending.get(message.ref_type) == message.ref_seq
        if isinstance(message, Nak) and not answers:
            return "NAK:OTHER"
        return f"{message.NAME}:{COMMAND_NAMES.get(message.ref_type, 'OTHER')}"
    if isinstance(message, Status) and message.alarms & Alarm.WATCHDOG_EXPIRED:
        return "STATUS:WATCHDOG"
    return message.NAME


def next_state(state: State, sender: Role, kind: str) -> State | None:
    """The state after ``sender`` emits ``kind`` in ``state``, or None if that is illegal."""
    return TRANSITIONS.get((state, sender, kind))


def legal_states(sender: Role, kind: str) -> list[State]:
    """The states in which ``sender`` may emit ``kind`` (for error messages)."""
    return [s for s in State if (s, sender, kind) in TRANSITIONS]


def illegal_message(state: State, sender: Role, kind: str, *, local: bool) -> str:
    """A sentence explaining why ``kind`` is illegal now and what to do instead."""
    legal = ", ".join(s.value for s in legal_states(sender, kind)) or "no state"
    if local:
        hint = _HINTS.get(kind.split(":")[0], "check the state machine in SPEC.md")
        return (
            f"{sender.name} cannot send {kind} in state {state.value}: it is legal only in"
            f" {legal}; {hint}"
        )
    return (
        f"{sender.name} sent {kind} in state {state.value}, where it is illegal (legal in"
        f" {legal}); the peer broke the protocol: log it, send STOP and reconnect if it"
        " repeats"
    )
