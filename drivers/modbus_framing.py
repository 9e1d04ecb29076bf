"""Modbus TCP framing: where one MBAP frame ends in a byte stream, and when it cannot.

The server cuts the TCP stream into frames itself (pymodbus's framer waits forever on a
bad header and drops its buffer past 264 bytes). An MBAP header is transaction id,
protocol id and length (2 bytes each, big-endian) and the unit id; the length counts the
unit id and the PDU, and a PDU is 1..253 bytes (Modbus Application Protocol V1.1b3,
4.1 and MBAP header 3.1.3 of "Modbus Messaging on TCP/IP"). A header with another
protocol id or length cannot be resynchronised on a byte stream without frame markers:
whatever follows would be read at the wrong offsets, so the caller closes the connection.
"""
from __future__ import annotations

import struct

#: MBAP header: transaction id, protocol id, length (2 bytes each), unit id.
MBAP_HEADER_BYTES = 7
#: The MBAP length counts the unit id and the PDU; a PDU is 1..253 bytes.
MBAP_LENGTH_MIN, MBAP_LENGTH_MAX = 2, 254
#: Bytes before the length's count starts: transaction id, protocol id, length.
_LENGTH_COUNTS_FROM = 6


class BadMbapHeader(ValueError):
    """A header no frame can follow (its protocol id or length is impossible)."""


def mbap_frame_end(buffer: bytes | bytearray, start: int) -> int | None:
    """The offset just past the frame that starts at `start`, None while the header or the
    frame is still incomplete; BadMbapHeader (naming the fields) for a header that no
    frame can follow."""
    if len(buffer) - start < MBAP_HEADER_BYTES:
        return None
    _, protocol_id, length = struct.unpack_from(">HHH", buffer, start)
    if protocol_id != 0 or not MBAP_LENGTH_MIN <= length <= MBAP_LENGTH_MAX:
        raise BadMbapHeader(f"bad MBAP header (protocol id {protocol_id}, length {length})")
    end = start + _LENGTH_COUNTS_FROM + length
    return end if len(buffer) >= end else None
