"""One conformance suite for every board implementation: the Python simulated board and the
C reference firmware (``firmware_protocol/c``), stepped on the same injected board clock.

- the golden conversations (``firmware_protocol/golden_conversations.json``): every step's
  device bytes, exactly (a NAK's free detail text aside);
- behaviour checks that decode the device's answers (refusal order, credits, watchdog);
- a differential protocol fuzz: seeded random host streams (legal, illegal, mutated and
  noise frames at random board times) must get the same answer from both implementations.

The C build needs ``cc`` and ``make``: without them the C cases skip, except under
``HIL_REQUIRE_SYSTEM_DEPS=1`` (CI), where they fail.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from firmware_protocol import (
    NEED_DATA,
    SCHEMA_HASH,
    AdcData,
    Alarm,
    Configure,
    Connection,
    Credit,
    DacData,
    Hello,
    Keepalive,
    Nak,
    NakCode,
    Role,
    SampleFormat,
    Start,
    State,
    Status,
    Stop,
    Sync,
    cobs,
    conversations,
)
from firmware_protocol.conversations import (
    CONFIG,
    CONVERSATIONS_PATH,
    Device,
    Host,
    describe,
    frames_of,
    idx,
    same_output,
)
from firmware_protocol.framing import encode_frame
from sim_devices.board import c_firmware
from sim_devices.board.stepper import PythonBoardStepper, conversation_spec

DOC: dict[str, Any] = json.loads(CONVERSATIONS_PATH.read_text(encoding="utf-8"))
IMPLS = ("python", "c")
MS = 1_000_000


@pytest.fixture(params=IMPLS)
def make_device(
    request: pytest.FixtureRequest, require_system: Callable[[bool, str], None]
) -> Callable[[], Device]:
    """A factory of fresh boards (powered up at board time 0) of one implementation."""
    if request.param == "python":
        return PythonBoardStepper
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not built: {missing}")
    return c_firmware.CBoardStepper


def diff(expected: bytes, got: bytes) -> str:
    """The two outputs frame by frame, for an assertion message."""
    a = [describe(f) for f in frames_of(expected)]
    b = [describe(f) for f in frames_of(got)]
    rows = [f"  expected {x[:150]}\n  got      {y[:150]}" for x, y in zip(a, b, strict=False)]
    rows += [f"  expected {x[:150]}" for x in a[len(b) :]]
    rows += [f"  got      {y[:150]}" for y in b[len(a) :]]
    return "\n".join(rows)


def test_conversations_file_is_what_the_reference_board_says() -> None:
    assert conversations.main(PythonBoardStepper, ["--check"]) == 0


def test_conversations_cover_every_refusal_a_reference_board_sends() -> None:
    codes = set()
    for conversation in DOC["conversations"]:
        for step in conversation["steps"]:
            for frame in frames_of(bytes.fromhex(step["device_hex"])):
                if frame[2] == Nak.TYPE_ID:
                    codes.add(frame[8 + 3])
    assert codes == set(range(1, 11))  # every code but INTERNAL (SPEC section 4)


@pytest.mark.parametrize("conversation", DOC["conversations"], ids=lambda c: c["name"])
def test_golden_conversation(
    make_device: Callable[[], Device], conversation: dict[str, Any]
) -> None:
    device = make_device()
    for number, step in enumerate(conversation["steps"]):
        got = device.step(step["t_ns"], bytes.fromhex(step["host_hex"]))
        expected = bytes.fromhex(step["device_hex"])
        assert same_output(expected, got), (
            f"{conversation['name']} step {number} at {step['t_ns'] / 1e6} ms:\n"
            + diff(expected, got)
        )


# --- behaviour, decoded -------------------------------------------------------------------


def messages(wire: bytes) -> list[Any]:
    """The device's frames decoded by a host-side reader (no state checks)."""
    from firmware_protocol.messages import MESSAGE_TYPES

    out = []
    for frame in frames_of(wire):
        cls = MESSAGE_TYPES[frame[2]]
        out.append(cls.decode_payload(frame[8:-4]))
    return out


def configured(make_device: Callable[[], Device]) -> tuple[Device, Host]:
    device = make_device()
    h = Host()
    device.step(0, h.frame(Hello(2, 0, SCHEMA_HASH)))
    device.step(1 * MS, h.frame(CONFIG))
    return device, h


def test_a_refused_configure_unconfigures_and_dac_data_is_then_refused(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)
    bad = Configure(12345, 0b11, 0b11, SampleFormat.INT16, SampleFormat.INT16)
    [nak] = messages(device.step(2 * MS, h.frame(bad)))
    assert (nak.ref_seq, nak.ref_type, nak.code) == (2, Configure.TYPE_ID, NakCode.UNSUPPORTED_RATE)
    [nak] = messages(device.step(3 * MS, h.dac(idx(10), 10)))
    assert (nak.ref_type, nak.code) == (DacData.TYPE_ID, NakCode.BAD_STATE)


def test_c_board_counts_one_adc_overrun_per_run_of_lost_indices(
    require_system: Callable[[bool, str], None],
) -> None:
    # SPEC 5.4: adc_overruns counts runs of consecutive lost indices (as dac_underruns
    # counts runs of unplayed ones), not frames. A 3 s stall of the link at 4 MB/s fills
    # the C board's 8 MiB send buffer: the frames that do not fit are lost, one run.
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not built: {missing}")
    device, h = c_firmware.CBoardStepper(), Host()
    i16 = SampleFormat.INT16
    device.step(0, h.frame(Hello(2, 0, SCHEMA_HASH)))
    device.step(1 * MS, h.frame(Configure(1_000_000, 0b11, 0b11, i16, i16)))
    device.step(2 * MS, h.frame(Start(11_000)))
    out = messages(device.step(3000 * MS, b""))
    adc = [m for m in out if isinstance(m, AdcData)]
    firsts = np.array([m.first_sample_index for m in adc])
    ends = firsts + np.array([m.sample_count for m in adc])
    holes = np.flatnonzero(firsts[1:] != ends[:-1])
    assert holes.size == 1  # one run of lost indices, between two frames that fitted
    [status] = [m for m in out if isinstance(m, Status)]
    assert status.adc_overruns == 1 and status.alarms & Alarm.ADC_OVERRUN
    out = messages(device.step(3001 * MS, h.frame(Stop())))
    assert [m.first_sample_index for m in out if isinstance(m, AdcData)] == [3_000_000]


def test_credit_comes_back_in_eighths_as_the_dac_plays(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)  # CREDIT 2048: the whole buffer
    device.step(2 * MS, h.dac(idx(5), 2000))  # 48 frames of credit left
    device.step(3 * MS, h.frame(Start(idx(5))))
    credits = []
    for t in range(4, 60):  # 48 frames play per ms: all 2000 by 47 ms
        out = messages(device.step(t * MS, b""))
        credits += [m.credit_samples for m in out if isinstance(m, Credit)]
    # SPEC 5.5: free = 2048 - level - outstanding = frames played and not yet granted; a
    # grant goes out once it reaches 2048 / 8, so what is left at the end is below that.
    assert credits[0] == 288  # the first service at which 256 or more had played (6 ms)
    assert all(c >= 256 for c in credits)
    assert 0 <= 2000 - sum(credits) < 256


def test_watchdog_fires_once_then_waits_for_a_keepalive(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)
    device.step(2 * MS, h.frame(Keepalive(10)))
    out = [m for t in range(3, 40) for m in messages(device.step(t * MS, b""))]
    fired = [m for m in out if isinstance(m, Status) and m.alarms & 0x2]
    assert len(fired) == 1 and fired[0].sample_index == idx(12)


def test_a_short_hello_in_a_session_is_refused_and_the_session_goes_on(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)
    [nak] = messages(device.step(2 * MS, h.frame(Hello(2, 0, SCHEMA_HASH), payload=b"\x02\x00")))
    assert (nak.ref_seq, nak.ref_type, nak.code) == (2, Hello.TYPE_ID, NakCode.BAD_PAYLOAD)
    assert messages(device.step(3 * MS, h.dac(idx(10), 10))) == []  # still configured


def test_a_refused_configure_keeps_the_clock_at_the_acknowledged_rate(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)  # 48 kHz from 1 ms; SYNC sent with the ACK
    device.step(
        2 * MS, h.frame(Configure(12345, 0b11, 0b11, SampleFormat.INT16, SampleFormat.INT16))
    )
    [sync] = [m for m in messages(device.step(150 * MS, b"")) if isinstance(m, Sync)]
    assert (sync.sample_index, sync.board_time_ns) == (idx(150), 150 * MS)


def test_the_watchdog_status_leaves_the_status_timer_alone(
    make_device: Callable[[], Device],
) -> None:
    device, h = configured(make_device)  # periodic STATUS at 1 ms, next due at 251 ms
    device.step(2 * MS, h.frame(Keepalive(10)))
    [fired] = [m for m in messages(device.step(13 * MS, b"")) if isinstance(m, Status)]
    assert (fired.alarms, fired.sample_index) == (0x2, idx(12))
    assert [m for m in messages(device.step(250 * MS, b"")) if isinstance(m, Status)] == []
    [periodic] = [m for m in messages(device.step(251 * MS, b"")) if isinstance(m, Status)]
    assert (periodic.alarms, periodic.sample_index) == (0, idx(251))


@pytest.mark.parametrize(
    ("adc_format", "full_scale"), [(SampleFormat.INT16, 32768), (SampleFormat.INT24, 8388608)]
)
def test_float32_dac_data_converts_to_adc_counts_as_spec_6_3_states(
    make_device: Callable[[], Device], adc_format: SampleFormat, full_scale: int
) -> None:
    """NaN reads 0 unclipped, +-inf and +1.0 clip, halves round to even (both boards), and
    both boards count the two clipped values (the count is not on the wire)."""
    board = dict(conversations.BOARD, formats=["INT16", "INT24", "FLOAT32"])
    maker = (
        (lambda: PythonBoardStepper(conversation_spec(board)))
        if make_device is PythonBoardStepper
        else (lambda: c_firmware.CBoardStepper(board))
    )
    device, h = maker(), Host()
    device.step(0, h.frame(Hello(2, 0, SCHEMA_HASH)))
    device.step(1 * MS, h.frame(Configure(48_000, 0b01, 0b01, SampleFormat.FLOAT32, adc_format)))
    values = [np.nan, 1.0, -np.inf, -1.0, 2.5 / full_scale, -2.5 / full_scale]
    samples = np.array(values, dtype=np.float32).reshape(-1, 1)
    device.step(2 * MS, h.frame(DacData.from_array(idx(5), 0b01, SampleFormat.FLOAT32, samples)))
    device.step(3 * MS, h.frame(Start(idx(5))))
    out = messages(device.step(6 * MS, b""))
    [adc] = [m for m in out if isinstance(m, AdcData)]
    assert adc.first_sample_index == idx(5)
    expected = [0, full_scale - 1, -full_scale, -full_scale, 2, -2]
    assert adc.samples()[:6, 0].tolist() == expected
    assert adc.samples()[6:, 0].tolist() == [0] * (adc.sample_count - 6)
    assert device.adc_clipped_samples == 2  # +1.0 and -inf; -1.0 is the bottom code


@pytest.mark.parametrize(
    ("dac_mask", "adc_mask", "expected"),
    [(0b10, 0b01, [[1000]]), (0b01, 0b11, [[1000, 0]]), (0b11, 0b10, [[1000]])],
)
def test_the_loopback_world_matches_channels_by_position(
    make_device: Callable[[], Device], dac_mask: int, adc_mask: int, expected: list[list[int]]
) -> None:
    """SPEC 6.3: the j-th enabled ADC channel reads the j-th enabled DAC channel, else 0;
    an INT16 DAC count c reads c * 256 on an INT24 ADC."""
    device, h = make_device(), Host()
    device.step(0, h.frame(Hello(2, 0, SCHEMA_HASH)))
    int16, int24 = SampleFormat.INT16, SampleFormat.INT24
    device.step(1 * MS, h.frame(Configure(48_000, dac_mask, adc_mask, int16, int24)))
    n_dac = bin(dac_mask).count("1")
    samples = np.tile(np.array([1000, -7][:n_dac], dtype=np.int16), (4, 1))
    device.step(2 * MS, h.frame(DacData.from_array(idx(5), dac_mask, int16, samples)))
    device.step(3 * MS, h.frame(Start(idx(5))))
    [adc] = [m for m in messages(device.step(6 * MS, b"")) if isinstance(m, AdcData)]
    assert adc.samples()[:4].tolist() == [[256 * v for v in expected[0]]] * 4


def _nak_frame(code: int, detail: bytes, seq: int = 7) -> bytes:
    payload = bytes([3, 0, Stop.TYPE_ID, code, len(detail)]) + detail
    return encode_frame(Nak.TYPE_ID, payload, seq)


def test_nak_frames_are_compared_by_fields_and_the_detail_is_free() -> None:
    expected = _nak_frame(3, b"a Python board's long explanation")
    assert same_output(expected, _nak_frame(3, b"short"))
    assert same_output(expected, _nak_frame(3, b""))
    assert not same_output(expected, _nak_frame(2, b"short"))  # another code
    assert not same_output(expected, _nak_frame(3, b"short", seq=8))  # another seq
    assert not same_output(expected, _nak_frame(3, b"\xff\xfe"))  # not UTF-8
    damaged = bytearray(cobs.decode(_nak_frame(3, b"short")[:-1]))
    damaged[-1] ^= 1  # a wrong CRC
    assert not same_output(expected, cobs.encode(bytes(damaged)) + b"\0")
    too_long = _nak_frame(3, b"short")
    assert not same_output(expected, too_long + too_long)  # one frame more


def test_frames_other_than_nak_are_compared_byte_for_byte() -> None:
    a = encode_frame(Stop.TYPE_ID + 0x2E, bytes([7, 0, Stop.TYPE_ID]), 4)  # ACK of STOP
    b = encode_frame(Stop.TYPE_ID + 0x2E, bytes([8, 0, Stop.TYPE_ID]), 4)
    assert same_output(a, b"\0" + a)  # an extra delimiter is an empty frame
    assert not same_output(a, b)


# --- differential fuzz ----------------------------------------------------------------------

N_SESSIONS = 60
STEPS = 40


def _random_frame(h: Host, rng: np.random.Generator, t_ms: float) -> bytes:
    kind = int(rng.integers(0, 12))
    fmt = SampleFormat.INT16
    if kind == 0:
        return h.frame(Hello(2, 0, SCHEMA_HASH))
    if kind == 1:
        rate = int(rng.choice([48_000, 96_000, 44_100]))
        masks = [1, 2, 3, 4]
        dac_gain, adc_gain = int(rng.integers(-5000, 5000)), int(rng.integers(-700, 700))
        dac_mask, adc_mask = int(rng.choice(masks)), int(rng.choice(masks))
        return h.frame(Configure(rate, dac_mask, adc_mask, fmt, fmt, dac_gain, adc_gain))
    if kind == 2:
        return h.frame(Start(max(0, idx(t_ms) + int(rng.integers(-200, 800)))))
    if kind == 3:
        return h.frame(Stop())
    if kind == 4:
        return h.frame(Keepalive(int(rng.integers(1, 40))))
    if kind in (5, 6, 7):
        first = max(0, idx(t_ms) + int(rng.integers(-300, 1500)))
        return h.dac(first, int(rng.integers(1, 700)), value=int(rng.integers(-30000, 30000)))
    if kind == 8:  # random type and payload
        payload = rng.integers(0, 256, int(rng.integers(0, 30)), dtype=np.uint8).tobytes()
        type_id, flags = int(rng.integers(0, 256)), int(rng.integers(0, 2))
        return h.frame(Stop(), type_id=type_id, payload=payload, flags=flags)
    if kind == 9:  # a known command with a truncated payload
        message = Configure(48_000, 3, 3, fmt, fmt)
        return h.frame(message, payload=message.encode_payload()[: int(rng.integers(0, 14))])
    wire = bytearray(h.frame(Keepalive(20)))  # a damaged frame or noise
    if kind == 10:
        wire[int(rng.integers(0, len(wire) - 1))] ^= int(rng.integers(1, 256))
        return bytes(wire)
    return rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()


@pytest.mark.slow
def test_python_and_c_boards_answer_random_host_streams_alike(
    require_system: Callable[[bool, str], None],
) -> None:
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not built: {missing}")
    rng = np.random.default_rng(21)
    frames = 0
    for session in range(N_SESSIONS):
        py, c = PythonBoardStepper(), c_firmware.CBoardStepper()
        h = Host()
        t = 0.0
        for step in range(STEPS):
            t += float(rng.choice([0.0, 0.5, 1.0, 3.0, 11.0, 40.0]))
            burst = b"".join(_random_frame(h, rng, t) for _ in range(int(rng.integers(0, 4))))
            if step == 0:
                burst = h.frame(Hello(2, 0, SCHEMA_HASH)) + burst
            t_ns = round(t * MS)
            a, b = py.step(t_ns, burst), c.step(t_ns, burst)
            frames += len(frames_of(a))
            assert same_output(a, b), f"session {session} step {step} at {t} ms:\n" + diff(a, b)
    assert frames > 2000  # the streams got answers, not just silence


def test_a_host_connection_accepts_everything_the_c_board_says_in_a_session(
    require_system: Callable[[bool, str], None],
) -> None:
    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not built: {missing}")
    device = c_firmware.CBoardStepper()
    host = Connection(Role.HOST)
    events: list[str] = []

    def step(t_ms: int, sent: bytes = b"") -> None:
        answer = device.step(t_ms * MS, sent)
        if answer:  # b"" would mean the end of the stream
            host.receive_data(answer)
        while (event := host.next_event()) is not NEED_DATA:
            events.append(type(event).__name__)

    step(0, host.send(host.make_hello()))
    step(1, host.send(CONFIG))
    step(2, host.send(Start(idx(5))))
    for t in range(3, 30):
        step(t)
    step(30, host.send(Stop()))
    assert host.state is State.STOPPED and host.stats.frame_errors == 0
    assert events[:2] == ["Version", "Capabilities"] and events[-2:] == ["Ack", "Credit"]
    assert events.count("AdcData") == 25  # one frame per 1 ms service from 5 ms to 30 ms


def test_c_receiver_counts_intact_and_damaged_frames_as_the_python_decoder_does(
    require_system: Callable[[bool, str], None],
) -> None:
    """Byte-level fuzz of the C receiver: 20 000 frames (a third damaged: bit flips, stray
    delimiters, cuts, insertions; plus noise), fed in random chunks, never crash it, and it
    counts good and bad frames exactly as ``FrameDecoder`` does (SPEC 1.3)."""
    from firmware_protocol import FrameDecoder, encode_frame

    missing = c_firmware.toolchain_missing()
    require_system(missing is None, f"C firmware not built: {missing}")
    rng = np.random.default_rng(13)
    parts = []
    for i in range(20_000):
        # Unknown optional types: the IDLE board answers nothing, so only its counters move.
        payload = rng.integers(0, 256, int(rng.integers(0, 64)), dtype=np.uint8).tobytes()
        wire = bytearray(encode_frame(0x7F, payload, i % 65536, flags=1))
        if i % 3 == 0:
            pos = int(rng.integers(0, len(wire) - 1))
            kind = i % 4
            if kind == 0:
                wire[pos] ^= int(rng.integers(1, 256))
            elif kind == 1:
                wire[pos] = 0
            elif kind == 2:
                del wire[pos]
            else:
                wire.insert(pos, int(rng.integers(0, 256)))
        parts.append(bytes(wire))
        if i % 500 == 0:
            parts.append(rng.integers(0, 256, 9000, dtype=np.uint8).tobytes())  # oversize noise
    stream = b"".join(parts)
    decoder = FrameDecoder()
    device = c_firmware.CBoardStepper()
    cuts = np.sort(rng.integers(0, len(stream), 3000))
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(stream)], strict=True):
        chunk = stream[a:b]
        decoder.feed(chunk)
        while decoder.next_frame() is not None:
            pass
        assert device.receive(chunk) == b""
    assert decoder.stats.frames_ok > 10_000
    assert device.frames_ok == decoder.stats.frames_ok
    assert device.frame_errors == decoder.stats.frame_errors
