"""MBAP framing on its own: where a frame ends, when it is incomplete, which headers no
frame can follow (Modbus Messaging on TCP/IP, 3.1.3: protocol id 0, length 2..254)."""
import struct

import pytest

from drivers.modbus_framing import MBAP_HEADER_BYTES, MBAP_LENGTH_MAX, MBAP_LENGTH_MIN, BadMbapHeader, mbap_frame_end


def header(length: int, protocol_id: int = 0, transaction: int = 7) -> bytes:
    return struct.pack(">HHH", transaction, protocol_id, length) + b"\x01"


def test_a_complete_frame_ends_after_its_length_and_the_next_starts_there() -> None:
    read = header(6) + b"\x04\x00\x00\x00\x01"  # unit id + FC04 address 0 count 1
    stream = read + read + read[:3]
    first = mbap_frame_end(stream, 0)
    assert first == len(read)
    assert mbap_frame_end(stream, first) == 2 * len(read)
    assert mbap_frame_end(stream, 2 * len(read)) is None  # the third is cut inside its header


@pytest.mark.parametrize("missing", [1, 3])
def test_an_incomplete_frame_waits(missing: int) -> None:
    frame = header(6) + b"\x04\x00\x00\x00\x01"
    assert mbap_frame_end(frame[:-missing], 0) is None
    assert mbap_frame_end(frame[: MBAP_HEADER_BYTES - 1], 0) is None


@pytest.mark.parametrize("length", [MBAP_LENGTH_MIN, MBAP_LENGTH_MAX])
def test_the_shortest_and_the_longest_lengths_are_frames(length: int) -> None:
    frame = header(length) + bytes(length - 1)
    assert mbap_frame_end(frame, 0) == len(frame)


@pytest.mark.parametrize(("protocol_id", "length"), [(1, 6), (0xFFFF, 6), (0, 0), (0, 1), (0, MBAP_LENGTH_MAX + 1)])
def test_a_header_no_frame_can_follow_is_refused_with_its_fields(protocol_id: int, length: int) -> None:
    with pytest.raises(BadMbapHeader, match=f"protocol id {protocol_id}, length {length}"):
        mbap_frame_end(header(length, protocol_id) + bytes(300), 0)
