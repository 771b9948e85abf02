"""Scripted HOST <-> DEVICE sessions over two Connection objects wired together."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from firmware_protocol import (
    NEED_DATA,
    SCHEMA_HASH,
    Ack,
    AdcData,
    Alarm,
    Capabilities,
    Configure,
    Connection,
    ConnectionClosed,
    Credit,
    DacData,
    FrameError,
    Hello,
    IncompatiblePeerError,
    Keepalive,
    LocalProtocolError,
    Log,
    LogLevel,
    Nak,
    NakCode,
    RemoteProtocolError,
    Role,
    SampleFormat,
    SequenceGap,
    Start,
    State,
    Status,
    Stop,
    Sync,
    UnknownMessage,
    Version,
    encode_frame,
)
from firmware_protocol.states import _ROWS, TRANSITIONS

CONFIG = Configure(1_000_000, 0b01, 0b11, SampleFormat.INT16, SampleFormat.INT16, 0, 1200)
CAPS = Capabilities(1, 2, 0b111, 4096, 8192, 8192, -2000, 4000, (1_000_000,))


def deliver(sender: Connection, receiver: Connection, message: Any) -> list[Any]:
    """Send one message and return every event the receiver gets from its bytes."""
    receiver.receive_data(sender.send(message))
    events = []
    while (event := receiver.next_event()) is not NEED_DATA:
        events.append(event)
        if isinstance(event, ConnectionClosed):  # repeated forever once closed (as in h11)
            break
    return events


def handshake() -> tuple[Connection, Connection]:
    host, board = Connection(Role.HOST), Connection(Role.DEVICE)
    assert deliver(host, board, host.make_hello()) == [host.make_hello()]
    version = board.make_version((1, 2, 3), 42)
    assert deliver(board, host, version) == [version]
    assert deliver(board, host, CAPS) == [CAPS]
    assert host.state is board.state is State.READY
    assert host.capabilities == CAPS and host.peer_version == version
    return host, board


def configured() -> tuple[Connection, Connection]:
    host, board = handshake()
    seq = host._tx_seq
    assert deliver(host, board, CONFIG) == [CONFIG]
    assert host.state is board.state is State.CONFIGURING
    assert deliver(board, host, Ack(seq, Configure.TYPE_ID)) == [Ack(seq, Configure.TYPE_ID)]
    assert host.state is board.state is State.CONFIGURED
    assert host.configuration == board.configuration == CONFIG
    return host, board


def test_full_session_handshake_to_stop() -> None:
    host, board = configured()
    # Credits, then DAC data preloaded before START.
    deliver(board, host, Credit(1000))
    assert host.dac_credit == board.dac_credit == 1000
    tone = (8000 * np.sin(np.arange(600) * 0.1)).astype(np.int16)[:, None]
    dac = DacData.from_array(5000, 0b01, SampleFormat.INT16, tone)
    [got] = deliver(host, board, dac)
    assert isinstance(got, DacData) and np.array_equal(got.samples(), tone)
    assert host.dac_credit == board.dac_credit == 400
    # Start at a sample index.
    start_seq = host._tx_seq
    assert deliver(host, board, Start(5000)) == [Start(5000)]
    deliver(board, host, Ack(start_seq, Start.TYPE_ID))
    assert host.state is board.state is State.STREAMING
    # ADC data, status, sync, keepalive, log.
    adc_block = np.arange(-50, 50, dtype=np.int16).reshape(50, 2)
    [adc] = deliver(board, host, AdcData.from_array(5000, 0b11, SampleFormat.INT16, adc_block))
    assert isinstance(adc, AdcData) and adc.first_sample_index == 5000
    np.testing.assert_array_equal(adc.samples(), adc_block)
    status = Status(5050, 400, 0, 0, 0, 3125, Alarm.ADC_CLIPPING)
    assert deliver(board, host, status) == [status]
    assert deliver(board, host, Sync(5050, 123_456_789)) == [Sync(5050, 123_456_789)]
    assert deliver(host, board, Keepalive(500)) == [Keepalive(500)]
    assert deliver(board, host, Log(LogLevel.INFO, "running")) == [Log(LogLevel.INFO, "running")]
    # Stop: ADC data in flight is still accepted, then the ACK.
    stop_seq = host._tx_seq
    deliver(host, board, Stop())
    assert host.state is board.state is State.STOPPING
    deliver(board, host, AdcData.from_array(5050, 0b11, SampleFormat.INT16, adc_block))
    deliver(board, host, Ack(stop_seq, Stop.TYPE_ID))
    assert host.state is board.state is State.STOPPED
    assert host.dac_credit == board.dac_credit == 0
    assert host.stats.frame_errors == host.stats.sequence_gaps == 0
    assert deliver(host, board, ConnectionClosed()) == [ConnectionClosed()]
    assert host.state is board.state is State.CLOSED


def test_nak_of_configure_leaves_both_sides_unconfigured() -> None:
    host, board = handshake()
    seq = host._tx_seq
    deliver(host, board, CONFIG)
    [nak] = deliver(
        board, host, Nak(seq, Configure.TYPE_ID, NakCode.UNSUPPORTED_RATE, "1 MHz only")
    )
    assert (
        isinstance(nak, Nak) and nak.code is NakCode.UNSUPPORTED_RATE and nak.detail == "1 MHz only"
    )
    assert host.state is board.state is State.READY and host.configuration is None


def test_watchdog_status_stops_the_session_on_both_sides() -> None:
    host, board = configured()
    seq = host._tx_seq
    deliver(host, board, Start(0))
    deliver(board, host, Ack(seq, Start.TYPE_ID))
    deliver(board, host, Status(100, 0, 0, 1, 0, 2500, Alarm.WATCHDOG_EXPIRED))
    assert host.state is board.state is State.STOPPED


def test_start_answered_after_stop_was_sent() -> None:
    host, board = configured()
    start_seq = host._tx_seq
    board.receive_data(host.send(Start(10)))
    stop_wire = host.send(Stop())  # the host stops before the START is answered
    assert board.next_event() == Start(10)
    deliver(board, host, Nak(start_seq, Start.TYPE_ID, NakCode.START_INDEX_PASSED))
    assert host.state is State.STOPPING and board.state is State.CONFIGURED
    board.receive_data(stop_wire)
    assert board.next_event() == Stop()
    deliver(board, host, Ack(start_seq + 1, Stop.TYPE_ID))
    assert host.state is board.state is State.STOPPED


# --- illegal sends -------------------------------------------------------------------------


def test_illegal_sends_raise_local_errors_with_clear_messages() -> None:
    host, board = handshake()
    with pytest.raises(
        LocalProtocolError,
        match="HOST cannot send START in state READY: it is legal only in CONFIGURED, STOPPED; send CONFIGURE and wait for its ACK first",  # noqa: E501
    ):
        host.send(Start(0))
    with pytest.raises(
        LocalProtocolError, match="HOST cannot send ADC_DATA: only the DEVICE sends it"
    ):
        host.send(AdcData(0, 1, SampleFormat.INT16, b"\x00\x00"))
    with pytest.raises(LocalProtocolError, match="DEVICE cannot send ADC_DATA in state READY"):
        board.send(AdcData(0, 1, SampleFormat.INT16, b"\x00\x00"))
    with pytest.raises(LocalProtocolError, match="cannot send FrameError: only messages"):
        host.send(FrameError.__new__(FrameError))  # type: ignore[arg-type]
    fresh = Connection(Role.HOST)
    with pytest.raises(LocalProtocolError, match="HOST cannot send CONFIGURE in state IDLE"):
        fresh.send(CONFIG)
    with pytest.raises(
        LocalProtocolError, match=r"HELLO states protocol 3\.0 .* build it with make_hello"
    ):
        fresh.send(Hello(3, 0, SCHEMA_HASH))
    assert fresh.state is State.IDLE and fresh._tx_seq == 0  # nothing was encoded


def test_credit_and_configuration_are_enforced_on_send() -> None:
    host, board = configured()
    deliver(board, host, Credit(100))
    too_much = DacData.from_array(0, 0b01, SampleFormat.INT16, np.zeros((101, 1), dtype=np.int16))
    with pytest.raises(
        LocalProtocolError,
        match="DAC_DATA of 101 samples exceeds the 100 samples of credit the device granted; send fewer samples or wait for CREDIT",  # noqa: E501
    ):
        host.send(too_much)
    wrong = DacData.from_array(0, 0b11, SampleFormat.INT16, np.zeros((10, 2), dtype=np.int16))
    with pytest.raises(
        LocalProtocolError,
        match="DAC_DATA has channel_mask 0x0003 and format INT16, but the configuration says 0x0001 and INT16",  # noqa: E501
    ):
        host.send(wrong)
    seq = host._tx_seq
    deliver(host, board, CONFIG)
    with pytest.raises(
        LocalProtocolError,
        match=f"ACK refers to CONFIGURE seq 999, but the CONFIGURE awaiting a reply has seq {seq}; replies must quote the command's seq",  # noqa: E501
    ):
        board.send(Ack(999, Configure.TYPE_ID))


def test_remote_violations_raise_remote_errors_and_reading_goes_on() -> None:
    host, board = configured()
    # The device grants nothing, but a rogue host sends DAC data anyway.
    rogue = Connection(Role.HOST)
    rogue.state, rogue.configuration, rogue.dac_credit, rogue._tx_seq = (
        State.CONFIGURED,
        CONFIG,
        50,
        host._tx_seq,
    )
    board.receive_data(rogue.send(DacData.from_array(0, 1, 1, np.zeros((50, 1), dtype=np.int16))))
    with pytest.raises(
        RemoteProtocolError,
        match="HOST sent DAC_DATA of 50 samples with only 0 samples of credit; answer NAK CREDIT_EXCEEDED",  # noqa: E501
    ):
        board.next_event()
    assert board.stats.remote_errors == 1 and board.state is State.CONFIGURED
    # An ADC frame before START is the board's fault, seen from the host.
    host.receive_data(
        encode_frame(
            AdcData.TYPE_ID,
            AdcData(0, 3, SampleFormat.INT16, b"\x00" * 4).encode_payload(),
            board._tx_seq,
        )
    )
    with pytest.raises(
        RemoteProtocolError,
        match="DEVICE sent ADC_DATA in state CONFIGURED, where it is illegal \\(legal in STREAMING, STOPPING\\)",  # noqa: E501
    ):
        host.next_event()
    # A frame of the wrong direction.
    host.receive_data(encode_frame(Start.TYPE_ID, Start(0).encode_payload(), board._tx_seq + 1))
    with pytest.raises(RemoteProtocolError, match="DEVICE sent START, which only the HOST sends"):
        host.next_event()
    board._tx_seq += 2  # the two injected frames used the board's next sequence numbers
    assert deliver(board, host, Sync(1, 2)) == [Sync(1, 2)]
    assert host.stats.remote_errors == 2


# --- versions ------------------------------------------------------------------------------


def test_board_of_another_major_version_is_refused() -> None:
    host = Connection(Role.HOST)
    board = Connection(Role.DEVICE, protocol_version=(3, 1), schema_hash=0x12345678)
    board.receive_data(host.send(host.make_hello()))
    assert board.next_event() == host.make_hello()
    assert board.refusal is not None and "host speaks 2.0" in board.refusal
    host.receive_data(board.send(board.make_version()))
    assert board.state is State.IDLE  # it waits for a compatible HELLO
    with pytest.raises(
        IncompatiblePeerError,
        match=r"board speaks protocol 3.1 \(schema 0x12345678\), host speaks 2.0 \(schema 0x[0-9a-f]{8}\): the major versions differ; update the host software to one that speaks protocol 3.x, or flash firmware built for protocol 2.x",  # noqa: E501
    ) as info:
        host.next_event()
    assert info.value.peer_version == (3, 1) and info.value.peer_schema == 0x12345678
    assert host.state is State.IDLE  # as the board: only a HELLO is legal now
    with pytest.raises(LocalProtocolError, match="in state IDLE"):
        host.send(CONFIG)


def test_after_an_incompatible_version_a_hello_reaches_a_board_flashed_meanwhile() -> None:
    host = Connection(Role.HOST)
    old = Connection(Role.DEVICE, protocol_version=(3, 1))
    deliver(host, old, host.make_hello())
    with pytest.raises(IncompatiblePeerError):
        deliver(old, host, old.make_version())
    flashed = Connection(Role.DEVICE)
    assert deliver(host, flashed, host.make_hello()) == [host.make_hello()]
    version = flashed.make_version((1, 0, 0), 7)
    assert deliver(flashed, host, version) == [version]
    assert deliver(flashed, host, CAPS) == [CAPS]
    assert host.state is flashed.state is State.READY and host.peer_version == version


def test_old_session_frames_between_hello_and_version_are_dropped_unseen() -> None:
    host, board = configured()
    deliver(host, board, Start(0))
    deliver(board, host, Ack(host._tx_seq - 1, Start.TYPE_ID))
    hello = host.send(host.make_hello())  # the host restarts the session (SPEC 5.1) ...
    # ... while the board, not yet reading it, still streams the old session:
    old = AdcData.from_array(0, 0b11, SampleFormat.INT16, np.zeros((4, 2), dtype=np.int16))
    in_flight = board.send(old) + board.send(Sync(4, 4000)) + board.send(Credit(64))
    board.receive_data(hello)
    assert board.next_event() == host.make_hello()
    version = board.make_version((1, 0, 0), 7)
    host.receive_data(in_flight + board.send(version) + board.send(CAPS))
    events = []
    while (event := host.next_event()) is not NEED_DATA:
        events.append(event)
    assert events == [version, CAPS]  # no error, and no sequence gap for the old numbering
    assert host.stats.stale_frames == 3 and host.stats.remote_errors == 0
    assert host.state is board.state is State.READY


def test_board_built_from_other_definitions_is_refused() -> None:
    host = Connection(Role.HOST)
    board = Connection(Role.DEVICE, schema_hash=SCHEMA_HASH ^ 0xFF)
    deliver(host, board, host.make_hello())
    with pytest.raises(
        IncompatiblePeerError,
        match=f"schema 0x{SCHEMA_HASH ^ 0xFF:08x}.*message definitions differ .* flash firmware built from this host's firmware_protocol/SPEC.md \\(schema 0x{SCHEMA_HASH:08x}\\)",  # noqa: E501
    ):
        deliver(board, host, board.make_version())


def test_board_of_another_minor_version_is_accepted() -> None:
    host = Connection(Role.HOST)
    board = Connection(Role.DEVICE, protocol_version=(2, 4))
    deliver(host, board, host.make_hello())
    assert board.refusal is None
    deliver(board, host, board.make_version())
    deliver(board, host, CAPS)
    assert host.state is State.READY and host.peer_version == Version(2, 4, SCHEMA_HASH, 0, 0, 0, 0)


# --- unknown messages, gaps, noise, end of stream ------------------------------------------


def test_unknown_messages_host_reports_device_naks() -> None:
    host, board = handshake()
    host.receive_data(encode_frame(0x7E, b"new", board._tx_seq))
    event = host.next_event()
    assert event == UnknownMessage(0x7E, board._tx_seq, 0, b"new") and host.state is State.READY
    board._tx_seq += 1
    board.receive_data(encode_frame(0x6A, b"\x01", host._tx_seq))
    unknown = board.next_event()
    assert isinstance(unknown, UnknownMessage) and not unknown.optional
    [nak] = deliver(board, host, unknown.nak())
    assert nak == Nak(unknown.seq, 0x6A, NakCode.UNKNOWN_MESSAGE, "unknown message type")
    board.receive_data(encode_frame(0x6B, b"", host._tx_seq + 1, flags=1))
    optional = board.next_event()
    assert isinstance(optional, UnknownMessage) and optional.optional
    assert board.stats.unknown_messages == 2


def test_sequence_gap_is_reported_before_the_message() -> None:
    host, board = configured()
    board.send(Sync(0, 0))  # these two frames are lost on the line
    board.send(Sync(1, 1))
    events = deliver(board, host, Sync(2, 2))
    expected_seq = board._tx_seq - 3
    assert events == [SequenceGap(expected_seq, expected_seq + 2, 2), Sync(2, 2)]
    assert host.stats.missed_frames == 2 and host.stats.sequence_gaps == 1


def test_noise_between_frames_is_an_event_and_end_of_stream_closes() -> None:
    host, board = handshake()
    host.receive_data(b"\x13\x37garbage\x00" + board.send(Sync(5, 6)))
    first, second = host.next_event(), host.next_event()
    assert isinstance(first, FrameError) and second == Sync(5, 6)
    host.receive_data(b"")
    assert host.next_event() == ConnectionClosed() and host.state is State.CLOSED


# --- the table -----------------------------------------------------------------------------


def test_transition_table_has_no_conflicting_rows() -> None:
    keys = [(s, sender, kind) for states, sender, kind, _ in _ROWS for s in states]
    assert len(keys) == len(set(keys)) == len(TRANSITIONS)


def test_every_state_is_reachable_and_left() -> None:
    targets = set(TRANSITIONS.values())
    sources = {s for s, _, _ in TRANSITIONS}
    assert targets == set(State) and sources == set(State)
