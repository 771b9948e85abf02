"""Golden vectors: the file on disk equals the generator, and every vector encodes/decodes."""

from __future__ import annotations

import json
import zlib
from typing import Any

import numpy as np
import pytest

from firmware_protocol import (
    NEED_DATA,
    PROTOCOL_MAJOR,
    SCHEMA_HASH,
    Connection,
    Frame,
    FrameDecoder,
    Role,
    SampleFormat,
    cobs,
    encode_frame,
    golden,
    unpack_samples,
)
from firmware_protocol.messages import MESSAGE_TYPES

DOC: dict[str, Any] = json.loads(golden.GOLDEN_PATH.read_text(encoding="utf-8"))


def test_file_on_disk_equals_what_the_code_generates() -> None:
    assert golden.GOLDEN_PATH.read_text(encoding="utf-8") == golden.render(), (
        "golden_vectors.json is stale: run python -m firmware_protocol.golden --write"
    )
    assert golden.main(["--check"]) == 0


def test_vectors_cover_every_message_type() -> None:
    assert {v["type_id"] for v in DOC["frames"]} == set(MESSAGE_TYPES)
    assert DOC["schema_hash"] == f"0x{SCHEMA_HASH:08x}"
    assert zlib.crc32(DOC["schema_text"].encode("ascii")) == SCHEMA_HASH


@pytest.mark.parametrize("vector", DOC["frames"], ids=lambda v: v["name"])
def test_vector_encodes_to_its_bytes_and_decodes_back(vector: dict[str, Any]) -> None:
    message = golden.message_from_fields(vector["message"], vector["fields"])
    payload = bytes.fromhex(vector["payload_hex"])
    wire = bytes.fromhex(vector["wire_hex"])
    frame = bytes.fromhex(vector["frame_hex"])
    assert message.encode_payload() == payload
    assert encode_frame(message.TYPE_ID, payload, vector["seq"], flags=vector["flags"]) == wire
    # The parts a firmware author checks one by one: COBS, header, CRC with its seed.
    assert wire[-1] == 0 and 0 not in wire[:-1] and cobs.decode(wire[:-1]) == frame
    seed = int(vector["crc_seed"], 16)
    assert frame[:8] == bytes([PROTOCOL_MAJOR, 0, vector["type_id"], vector["flags"]]) + vector[
        "seq"
    ].to_bytes(2, "little") + len(payload).to_bytes(2, "little")
    assert frame[8:-4] == payload
    assert (
        frame[-4:]
        == zlib.crc32(frame[:-4], seed).to_bytes(4, "little")
        == bytes.fromhex(vector["crc_hex"])
    )
    decoder = FrameDecoder()
    decoder.feed(wire)
    decoded = decoder.next_frame()
    assert isinstance(decoded, Frame) and decoded.seq == vector["seq"]
    assert MESSAGE_TYPES[decoded.type_id].decode_payload(decoded.payload) == message


def test_golden_values_a_reader_can_check_by_eye() -> None:
    by_name = {v["name"]: v for v in DOC["frames"]}
    assert by_name["stop"]["payload_hex"] == ""
    assert by_name["start"]["payload_hex"] == "40420f0000000000"  # 1 000 000 as u64 LE
    assert by_name["keepalive"]["payload_hex"] == "f401"  # 500 ms
    assert by_name["log"]["flags"] == 1  # LOG is sent with the OPTIONAL flag
    assert by_name["hello"]["crc_seed"] == "0x00000000"
    assert by_name["sync"]["crc_seed"] == f"0x{SCHEMA_HASH:08x}"
    assert by_name["sequence_wrap"]["frame_hex"][8:12] == "ffff"


@pytest.mark.parametrize("vector", DOC["cobs"], ids=lambda v: v["decoded_hex"][:12] or "empty")
def test_cobs_vectors(vector: dict[str, str]) -> None:
    assert cobs.encode(bytes.fromhex(vector["decoded_hex"])).hex() == vector["encoded_hex"]
    assert cobs.decode(bytes.fromhex(vector["encoded_hex"])).hex() == vector["decoded_hex"]


@pytest.mark.parametrize("vector", DOC["samples"], ids=lambda v: v["format"])
def test_sample_vectors(vector: dict[str, Any]) -> None:
    fmt = SampleFormat[vector["format"]]
    values = unpack_samples(bytes.fromhex(vector["hex"]), vector["channels"], fmt)
    np.testing.assert_array_equal(values, np.array(vector["values"]))


def test_a_board_replaying_the_golden_device_frames_is_understood() -> None:
    host = Connection(Role.HOST)
    host.send(host.make_hello())
    names = ("version", "capabilities")
    host.receive_data(
        b"".join(bytes.fromhex(v["wire_hex"]) for v in DOC["frames"] if v["name"] in names)
    )
    events = []
    while (event := host.next_event()) is not NEED_DATA:
        events.append(type(event).__name__)
    assert events == ["Version", "Capabilities"]
    assert host.state.name == "READY" and host.peer_version is not None
    assert host.peer_version.board_serial == 0xC0FFEE
