"""Message definitions: round trips of every type, validation messages, schema hash, SPEC."""

from __future__ import annotations

import re
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_protocol import (
    MESSAGE_TYPES,
    AdcData,
    Alarm,
    Capabilities,
    Configure,
    DacData,
    FieldValueError,
    Frame,
    FrameDecoder,
    Log,
    Message,
    Nak,
    NakCode,
    RemoteProtocolError,
    SampleFormat,
    Start,
    Status,
    encode_frame,
    schema,
)
from firmware_protocol.messages import Field

SPEC = Path(schema.__file__).with_name("SPEC.md").read_text(encoding="utf-8")


def _field_strategy(spec: Field) -> st.SearchStrategy[Any]:
    if spec.enum is Alarm:
        return st.integers(0, 0x3F).map(Alarm)
    if spec.enum is NakCode:
        return st.sampled_from(list(NakCode))
    if spec.enum is not None:
        return st.sampled_from(list(spec.enum))
    low, high = spec.bounds
    return st.integers(low, high)


@st.composite
def messages(draw: st.DrawFn, cls: type[Message]) -> Message:
    kwargs = {f.name: draw(_field_strategy(f)) for f in cls.LAYOUT if not f.derived}
    if cls in (DacData, AdcData):
        fmt = kwargs["sample_format"]
        channels = bin(kwargs["channel_mask"]).count("1")
        most = (8180 - 14) // (channels * fmt.size)
        frames = draw(st.integers(1, min(most, 64)))
        kwargs["data"] = draw(
            st.binary(min_size=frames * channels * fmt.size, max_size=frames * channels * fmt.size)
        )
    elif cls is Capabilities:
        kwargs["sample_rates_hz"] = tuple(
            draw(st.lists(st.integers(1, 2**32 - 1), min_size=1, max_size=32))
        )
        low, high = sorted((kwargs["gain_min_cdb"], kwargs["gain_max_cdb"]))
        kwargs["gain_min_cdb"], kwargs["gain_max_cdb"] = low, high
    elif cls is Log:
        kwargs["text"] = draw(st.text(max_size=200))
    elif cls is Nak:
        kwargs["detail"] = draw(st.text(max_size=60))
    return cls(**kwargs)


ALL = sorted(MESSAGE_TYPES.values(), key=lambda c: c.TYPE_ID)


@pytest.mark.parametrize("cls", ALL, ids=lambda c: c.NAME)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_message_round_trips_through_payload_and_frame(
    cls: type[Message], data: st.DataObject
) -> None:
    message = data.draw(messages(cls))
    payload = message.encode_payload()
    assert cls.decode_payload(payload) == message
    # A later minor version may append fields: extra bytes are ignored.
    assert cls.decode_payload(payload + b"\x99\x00\x01") == message
    seq = data.draw(st.integers(0, 65535))
    decoder = FrameDecoder()
    decoder.feed(encode_frame(cls.TYPE_ID, payload, seq))
    frame = decoder.next_frame()
    assert isinstance(frame, Frame)
    assert (frame.type_id, frame.seq, frame.payload) == (cls.TYPE_ID, seq, payload)
    assert decoder.next_frame() is None


def test_data_messages_round_trip_numpy_arrays() -> None:
    rng = np.random.default_rng(3)
    block = rng.integers(-(1 << 23), 1 << 23, (100, 3))
    msg = AdcData.from_array(10**12, 0b1011, SampleFormat.INT24, block)
    assert (msg.sample_count, msg.channels) == (100, 3)
    np.testing.assert_array_equal(AdcData.decode_payload(msg.encode_payload()).samples(), block)  # type: ignore[attr-defined]


# --- validation: raise before encoding, naming field, value and range -------------------------


def test_rate_zero_is_refused() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"^Configure.sample_rate_hz = 0 is not allowed: must be 1 \.\. 100000000 Hz",
    ):
        Configure(0, 1, 1, SampleFormat.INT16, SampleFormat.INT16)


def test_channel_mask_zero_is_refused() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"^Configure.adc_channel_mask = 0 is not allowed: must be 1 \.\. 65535 bit mask",
    ):
        Configure(1000, 1, 0, SampleFormat.INT16, SampleFormat.INT16)
    with pytest.raises(FieldValueError, match=r"^AdcData.channel_mask = 0 "):
        AdcData(0, 0, SampleFormat.INT16, b"\x00\x00")


def test_unknown_format_is_refused() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"^Configure.dac_format = 9 is not allowed: must be one of 1 \(INT16\), 2 \(INT24\), 3 \(FLOAT32\)",  # noqa: E501
    ):
        Configure(1000, 1, 1, 9, SampleFormat.INT16)  # type: ignore[arg-type]


def test_negative_sample_index_is_refused() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"^Start.start_sample_index = -1 is not allowed: must be 0 \.\. 18446744073709551615 samples",  # noqa: E501
    ):
        Start(-1)
    with pytest.raises(FieldValueError, match=r"^DacData.first_sample_index = -5 "):
        DacData(-5, 1, SampleFormat.INT16, b"\x00\x00")


def test_payload_too_long_for_the_frame_is_refused() -> None:
    too_many = np.zeros((4084, 1), dtype=np.int16)  # (8192 - 12 - 14) // 2 = 4083 fit
    with pytest.raises(
        FieldValueError,
        match=r"^DacData.data = '<8168 bytes>' is not allowed: must be 1 \.\. 4083 whole sample frames of 2 bytes .* 8192-byte frame limit; split the block",  # noqa: E501
    ):
        DacData.from_array(0, 1, SampleFormat.INT16, too_many)
    assert DacData.from_array(0, 1, SampleFormat.INT16, too_many[:4083]).sample_count == 4083
    with pytest.raises(
        FieldValueError, match=r"payload length = 8181 is not allowed: must be <= 8180 bytes"
    ):
        encode_frame(0x20, bytes(8181), 0)


def test_other_field_errors_name_the_field() -> None:
    with pytest.raises(
        FieldValueError,
        match=r"^AdcData.data = '<3 bytes>' .* whole sample frames of 4 bytes \(2 channels x INT16\)",  # noqa: E501
    ):
        AdcData(0, 0b11, SampleFormat.INT16, b"\x00\x01\x02")
    with pytest.raises(
        FieldValueError, match=r"^Configure.adc_gain_cdb = 20000 .* -12000 \.\. 12000 0.01 dB"
    ):
        Configure(1000, 1, 1, 1, 1, 0, 20000)  # type: ignore[arg-type]
    with pytest.raises(
        FieldValueError, match=r"^Status.temperature_cdeg = 1.5 is not allowed: must be an integer"
    ):
        Status(0, 0, 0, 0, 0, 1.5)  # type: ignore[arg-type]
    with pytest.raises(FieldValueError, match=r"^Nak.detail = '<300 UTF-8 bytes>' .* <= 255 bytes"):
        Nak(0, 0x10, NakCode.BUSY, "x" * 300)
    with pytest.raises(
        FieldValueError,
        match=r"^AdcData.samples.shape\[1\] = 2 .* 3 \(bits set in channel_mask 0x0007\)",
    ):
        AdcData.from_array(0, 0b111, SampleFormat.INT16, np.zeros((4, 2), dtype=np.int16))


def test_malformed_received_payloads_raise_remote_errors() -> None:
    with pytest.raises(
        RemoteProtocolError,
        match="CONFIGURE payload is 3 bytes, shorter than its 14-byte fixed part",
    ):
        Configure.decode_payload(b"\x00\x01\x02")
    bad_format = struct.pack("<QHHBB", 0, 1, 1, 7, 0) + b"\x00\x00"
    with pytest.raises(
        RemoteProtocolError, match=r"bad ADC_DATA: sample_format = 7 is not one of 1 \(INT16\)"
    ):
        AdcData.decode_payload(bad_format)
    short = struct.pack("<QHHBB", 0, 5, 1, 1, 0) + b"\x00\x00"
    with pytest.raises(
        RemoteProtocolError,
        match="ADC_DATA with sample_count = 5 needs 10 bytes but the payload has 2 left",
    ):
        AdcData.decode_payload(short)
    zero_rate = struct.pack("<IHHBBhh", 0, 1, 1, 1, 1, 0, 0)
    with pytest.raises(
        RemoteProtocolError, match=r"peer sent a bad CONFIGURE: Configure\.sample_rate_hz = 0"
    ):
        Configure.decode_payload(zero_rate)


def test_unknown_nak_codes_from_later_minors_are_kept_as_numbers() -> None:
    nak = Nak.decode_payload(struct.pack("<HBBB", 1, 0x10, 200, 0))
    assert nak == Nak(1, 0x10, 200)  # type: ignore[arg-type]


# --- schema hash and SPEC ----------------------------------------------------------------------


def test_schema_hash_is_the_crc_of_the_canonical_text() -> None:
    import zlib

    text = schema.canonical_text()
    assert zlib.crc32(text.encode("ascii")) == schema.SCHEMA_HASH
    assert text.startswith("cas-hil firmware protocol 2\nheader: protocol_major u8,")
    assert (
        "0x21 ADC_DATA device: first_sample_index u64, sample_count u16, channel_mask u16" in text
    )
    assert len(text.splitlines()) == 3 + len(MESSAGE_TYPES)


def test_schema_hash_changes_when_a_definition_changes(monkeypatch: pytest.MonkeyPatch) -> None:
    before = schema.compute_schema_hash()
    changed = (*Start.LAYOUT[:0], Field("start_sample_index", "u32", "samples"))
    monkeypatch.setattr(Start, "LAYOUT", changed)
    assert schema.compute_schema_hash() != before


def test_spec_states_the_schema_hash_and_every_layout_table() -> None:
    assert f"Schema hash of this document: **0x{schema.SCHEMA_HASH:08x}**" in SPEC
    for cls in ALL:
        assert f"### 0x{cls.TYPE_ID:02x} {cls.NAME} " in SPEC
        assert schema.layout_table(cls) in SPEC, f"SPEC.md table of {cls.NAME} is out of date"


def test_spec_offsets_add_up_to_the_struct_sizes() -> None:
    for cls in ALL:
        rows = re.findall(r"^\| (\d+) \| (\d+) \| \w+ \|", schema.layout_table(cls), re.M)
        end = max((int(o) + int(s) for o, s in rows), default=0)
        assert end == cls._STRUCT.size


def test_spec_generated_sections_equal_what_the_code_generates() -> None:
    from firmware_protocol import spec_tables

    assert spec_tables.render(SPEC) == SPEC, (
        "SPEC.md is stale: run python -m firmware_protocol.spec_tables --write"
    )
    assert spec_tables.main(["--check"]) == 0
    # The refusal table answers every host message in every state a device rests in.
    table = spec_tables.refusal_table()
    assert "| STREAMING | VERSION (+ CAPABILITIES) | NAK BAD_STATE | NAK BAD_STATE | ACK |" in table
    assert (
        "| READY | VERSION (+ CAPABILITIES) | ACK or NAK | NAK BAD_STATE | NAK BAD_STATE |" in table
    )
