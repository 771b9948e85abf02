"""The Board driver against a scripted transport: every write is checked byte for byte and
answered with frames built by the real protocol encoder (a DEVICE Connection)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from firmware_protocol import (
    NEED_DATA,
    Ack,
    AdcData,
    Capabilities,
    Configure,
    Connection,
    Credit,
    Keepalive,
    Message,
    Nak,
    NakCode,
    Role,
    SampleFormat,
    Start,
    Stop,
    Sync,
)
from hil.acquisition import AnnotationKind
from hil.devices.board import Board, BoardCommandError
from hil.devices.board_settings import BoardSettings
from hil.errors import ConfigError
from sim_devices.board import BoardSpec
from sim_devices.stage.clock import ManualClock

CAPS = BoardSpec().capabilities()
INT16 = SampleFormat.INT16


class ScriptedTransport:
    """Replays ``(expected write, response)`` pairs; records every write and mismatch."""

    def __init__(self, script: list[tuple[bytes, bytes]]) -> None:
        self.script = list(script)
        self.writes: list[bytes] = []
        self.mismatches: list[str] = []
        self.timeout = 0.01
        self.url = "scripted://"
        self._rx = bytearray()
        self._lock = threading.Lock()
        self._wrote = threading.Condition(self._lock)

    def write(self, data: bytes) -> int:
        with self._lock:
            self.writes.append(bytes(data))
            if not self.script:
                self.mismatches.append(f"unexpected write {bytes(data).hex()}")
                return len(data)
            expected, response = self.script.pop(0)
            if bytes(data) != expected:
                self.mismatches.append(f"wrote {bytes(data).hex()}, expected {expected.hex()}")
            self._rx += response
            self._wrote.notify_all()
        return len(data)

    def wait_for_writes(self, n: int, timeout_s: float = 30.0) -> bool:
        """Block until ``n`` writes have come (True) or ``timeout_s`` real seconds, a
        deadlock guard, have passed (False)."""
        with self._wrote:
            return self._wrote.wait_for(lambda: len(self.writes) >= n, timeout_s)

    def read(self, size: int) -> bytes:
        with self._lock:
            out = bytes(self._rx[:size])
            del self._rx[:size]
        if not out:
            time.sleep(self.timeout)
        return out

    def close(self) -> None:
        pass


class Script:
    """Builds the expected host bytes and the device's answers with two real Connections."""

    def __init__(self, caps: Capabilities = CAPS, *, version: tuple[int, int] = (2, 0)) -> None:
        self.host = Connection(Role.HOST)
        self.device = Connection(Role.DEVICE, protocol_version=version)
        self.caps = caps
        self.steps: list[tuple[bytes, bytes]] = []

    def step(self, message: Message, *answers: Message) -> None:
        wire = self.host.send(message)
        self.device.receive_data(wire)
        while self.device.next_event() is not NEED_DATA:
            pass
        reply = b"".join(self.device.send(a) for a in answers)
        if reply:
            self.host.receive_data(reply)
            while self.host.next_event() is not NEED_DATA:
                pass
        self.steps.append((wire, reply))

    def handshake(self) -> None:
        version = self.device.make_version((1, 2, 3), 42)
        wire = self.host.send(self.host.make_hello())
        self.device.receive_data(wire)
        self.device.next_event()
        answers = [version] + ([self.caps] if self.device.refusal is None else [])
        reply = b"".join(self.device.send(a) for a in answers)
        if self.device.refusal is None:
            self.host.receive_data(reply)
            while self.host.next_event() is not NEED_DATA:
                pass
        self.steps.append((wire, reply))


def test_open_configure_start_stream_stop() -> None:
    script = Script()
    script.handshake()
    config = BoardSettings().to_configure()
    script.step(config, Ack(1, Configure.TYPE_ID), Sync(1000, 5_000_000), Credit(1000))
    first = 1000 + 200_000  # the last SYNC plus the start lead (0.2 s at 1 MS/s)
    rng = np.random.default_rng(2)
    blocks = [rng.integers(-2000, 2000, (500, 2)).astype(np.int16) for _ in range(3)]
    script.step(
        Start(first),
        Ack(2, Start.TYPE_ID),
        AdcData.from_array(first, 0b11, INT16, blocks[0]),
        AdcData.from_array(first + 500, 0b11, INT16, blocks[1]),
        AdcData.from_array(first + 1500, 0b11, INT16, blocks[2]),  # 500 samples missing
    )
    script.step(Stop(), Ack(3, Stop.TYPE_ID))
    transport = ScriptedTransport(script.steps)
    board = Board(transport, clock=ManualClock(), keepalive_ms=None, ring_seconds=0.01)
    with board:
        assert board.version is not None and board.version.board_serial == 42
        board.configure()
        assert board.start() == first
        assert board.wait_for_samples(first + 2000, 5.0)
        board.stop()
    assert transport.mismatches == [] and transport.script == []
    np.testing.assert_array_equal(board.read(first, 1000), np.concatenate(blocks[:2]))
    np.testing.assert_array_equal(board.read(first + 1500, 500), blocks[2])
    gaps = board.annotations.of_kind(AnnotationKind.GAP)
    assert [(g.sample_index, g.length) for g in gaps] == [(first + 1000, 500)]
    assert board.samples_received == 1500 and board.ring is not None


def test_keepalive_follows_the_handshake() -> None:
    script = Script()
    script.handshake()
    script.step(Keepalive(500))
    transport = ScriptedTransport(script.steps)
    board = Board(transport, clock=ManualClock(), keepalive_ms=500)
    board.open()
    try:
        assert transport.wait_for_writes(2), f"no KEEPALIVE after the HELLO: {transport.writes}"
    finally:
        board.close()
    # The writer repeats the keepalive every 125 ms of (manual, frozen) clock: only once here.
    assert transport.mismatches == [] and transport.script == []


@pytest.mark.parametrize(
    ("version", "schema", "words"),
    [
        ((3, 1), None, "board speaks protocol 3.1 .* the major versions differ; update the host"),
        (
            (2, 0),
            0x12345678,
            r"board speaks protocol 2.0 \(schema 0x12345678\).*\(schema hash mismatch\)",
        ),
    ],
)
def test_incompatible_board_is_refused_with_a_clear_message(
    version: tuple[int, int], schema: int | None, words: str
) -> None:
    from firmware_protocol import IncompatiblePeerError

    script = Script(version=version)
    if schema is not None:
        script.device = Connection(Role.DEVICE, schema_hash=schema)
    script.handshake()
    transport = ScriptedTransport(script.steps)
    with pytest.raises(IncompatiblePeerError, match=f"scripted://: {words}"):
        Board(transport, keepalive_ms=None).open()
    assert len(transport.writes) == 1  # HELLO only: nothing else was sent


def test_invalid_settings_raise_before_anything_is_sent() -> None:
    with pytest.raises(
        ConfigError,
        match=r"sample_rate_hz = 0 is not allowed: must be 1 \.\. 100000000 Hz; the tank-board",
    ):
        BoardSettings(sample_rate_hz=0)
    with pytest.raises(
        ConfigError, match=r"dac_channels = 17 is not allowed: must be 1 \.\. 16 channels"
    ):
        BoardSettings(dac_channels=17)
    with pytest.raises(ConfigError, match="adc_format = 'int12' is not allowed: must be one of"):
        BoardSettings(adc_format="int12")
    script = Script()
    script.handshake()
    transport = ScriptedTransport(script.steps)
    board = Board(transport, keepalive_ms=None).open()
    try:
        written = list(transport.writes)
        with pytest.raises(
            ConfigError,
            match="sample_rate_hz = 123456 is not allowed: must be one of 1000000, 500000,",
        ):
            board.configure(BoardSettings(sample_rate_hz=123456))
        with pytest.raises(ConfigError, match=r"adc_gain_db = 50.0 .* must be -40.0 \.\. 40.0 dB"):
            board.configure(BoardSettings(adc_gain_db=50.0))
        assert transport.writes == written and transport.mismatches == []
    finally:
        board.close()


def test_unknown_setting_name_is_refused() -> None:
    with pytest.raises(ConfigError, match="board setting = 'rate' is not allowed: must be one of"):
        BoardSettings(rate=1)


def test_no_answer_to_hello_times_out_with_advice() -> None:
    from hil.errors import TransportTimeoutError

    transport = ScriptedTransport(
        [(Connection(Role.HOST).send(Connection(Role.HOST).make_hello()), b"")]
    )
    board = Board(transport, keepalive_ms=None, command_timeout_s=0.1)
    with pytest.raises(
        TransportTimeoutError, match=r"no VERSION within 0\.1 s; check that the board"
    ):
        board.open()


def test_start_refused_as_passed_is_retried_with_a_doubled_lead_then_given_up() -> None:
    """Each refusal: STOP (the board drops what it holds), a fresh look at the board clock,
    twice the lead; after start_attempts refusals, an error that says what to change."""
    script = Script()
    script.handshake()
    config = BoardSettings().to_configure()
    script.step(config, Ack(1, Configure.TYPE_ID), Sync(1000, 5_000_000))
    seq = 2
    sync = 1000
    firsts = []
    for lead in (200_000, 400_000, 800_000):
        first = sync + lead
        firsts.append(first)
        sync = first + 50_000  # the board's clock has passed it by the time START arrives
        passed = Nak(seq, Start.TYPE_ID, NakCode.START_INDEX_PASSED, f"clock is at {sync}")
        script.step(Start(first), passed, Sync(sync, 6_000_000))
        script.step(Stop(), Ack(seq + 1, Stop.TYPE_ID))
        seq += 2
    transport = ScriptedTransport(script.steps)
    board = Board(transport, clock=ManualClock(), keepalive_ms=None, ring_seconds=0.01)
    with board:
        board.configure()
        with pytest.raises(BoardCommandError) as info:
            board.start()
    assert transport.mismatches == [] and transport.script == []
    words = str(info.value)
    assert "refused START 3 times because its start index had passed" in words
    assert f"at {firsts[0]} with a 0.2 s lead" in words and "0.8 s lead" in words
    assert "Raise start_lead_s" in words


def test_start_refused_for_another_reason_is_not_retried() -> None:
    script = Script()
    script.handshake()
    config = BoardSettings().to_configure()
    script.step(config, Ack(1, Configure.TYPE_ID), Sync(1000, 5_000_000))
    script.step(Start(201_000), Nak(2, Start.TYPE_ID, NakCode.BUSY, "busy"))
    transport = ScriptedTransport(script.steps)
    board = Board(transport, clock=ManualClock(), keepalive_ms=None, ring_seconds=0.01)
    with board:
        board.configure()
        with pytest.raises(BoardCommandError, match=r"refused START with .*BUSY.*busy"):
            board.start()
        assert transport.script == []  # nothing more was sent: no STOP, no second START
    assert transport.mismatches == []


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"start_lead_s": 0.0}, r"start_lead_s = 0.0 is not allowed: must be in \(0, 10\] s"),
        ({"start_attempts": 0}, "start_attempts = 0 is not allowed: must be an integer in 1 .. 10"),
        ({"start_attempts": 2.5}, "start_attempts = 2.5 is not allowed"),
    ],
)
def test_bad_start_options_are_refused(options: dict[str, float], words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        Board("sim://board", **options)  # type: ignore[arg-type]
