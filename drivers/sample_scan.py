"""The decoder's hot case in compiled form: is there a good SAMPLE frame at this byte?

`StreamDecoder.feed` is the reference decoder; it runs ~70 Python steps per frame,
500 times a second. A compiled caller (the daemon's per-chunk sample path) asks
`sample_at` for the frame that starts at a position instead, and hands everything
that is not a complete, CRC-valid SAMPLE frame (garbage, a partial frame, STATUS,
HELLO) to `feed` — which then continues exactly where the compiled scan stopped (see
`StreamDecoder.account_samples`). tests/test_sample_fast_path.py checks that both
decode the same frames and counters from the same bytes.

Compiled with numba when it is installed and ADXLGW_NO_JIT is not set (the drivers do
not import the gateway's own switch: the same rule, restated here); plain Python
otherwise, where callers should use `feed` instead (`COMPILED` tells which).
"""
from __future__ import annotations

import binascii
import os

import numpy as np

from drivers.board_protocol import CRC_INITIAL, SAMPLE_FRAME_LENGTH, SYNC, FrameType, PAYLOAD_LENGTH

try:
    if os.environ.get("ADXLGW_NO_JIT"):
        raise ImportError("disabled by ADXLGW_NO_JIT")
    from numba import njit as _njit

    COMPILED = True

    def _compiled(func):
        return _njit(cache=True, nogil=True)(func)

except ImportError:
    COMPILED = False

    def _compiled(func):
        return func


# CRC-16/CCITT-FALSE by table, each entry from the reference implementation (binascii)
CRC_TABLE = np.array([binascii.crc_hqx(bytes((b,)), 0) for b in range(256)], dtype=np.int64)
_SYNC0, _SYNC1 = SYNC[0], SYNC[1]
_SAMPLE_TYPE = int(FrameType.SAMPLE)
_SAMPLE_N = PAYLOAD_LENGTH[FrameType.SAMPLE]
_FRAME_LEN = SAMPLE_FRAME_LENGTH


@_compiled
def sample_at(buf, pos):
    """(seq, t1x, t1y, t2, flags) of the SAMPLE frame starting at `pos`, or seq −1 when
    none starts there: no sync, another type or N, fewer than 15 bytes left, or a CRC
    mismatch. Integers are big-endian on the wire (shared spec)."""
    end = pos + _FRAME_LEN
    if end > buf.size or buf[pos] != _SYNC0 or buf[pos + 1] != _SYNC1:
        return -1, 0, 0, 0, 0
    if buf[pos + 2] != _SAMPLE_TYPE or buf[pos + 3] != _SAMPLE_N:
        return -1, 0, 0, 0, 0
    crc = CRC_INITIAL
    for i in range(pos + 2, end - 2):
        crc = ((crc << 8) & 0xFFFF) ^ CRC_TABLE[((crc >> 8) ^ buf[i]) & 0xFF]
    if crc != (np.int64(buf[end - 2]) << 8 | buf[end - 1]):
        return -1, 0, 0, 0, 0
    seq = np.int64(buf[pos + 4]) << 8 | buf[pos + 5]
    t1x = np.int64(buf[pos + 6]) << 8 | buf[pos + 7]
    t1y = np.int64(buf[pos + 8]) << 8 | buf[pos + 9]
    t2 = np.int64(buf[pos + 10]) << 8 | buf[pos + 11]
    return seq, t1x, t1y, t2, np.int64(buf[pos + 12])
