"""ADXL202 / 8051 board serial protocol, version 1: the stream decoder.

Turns serial bytes, in any chunking, into the frames of drivers/board_protocol.py (the
frame codec: constants, records, encoders). Decoding never raises: a serial line
delivers whatever it delivers, so bad bytes are counted in :class:`DecoderCounters` and
skipped, one byte at a time, until the next good frame.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass, replace
from typing import Protocol

from drivers.board_protocol import (
    _REPORT_PAYLOAD_CRC,
    CRC_INITIAL,
    HEADER_LENGTH,
    PAYLOAD_LENGTH,
    SAMPLE_FRAME_LENGTH,
    SEQ_BACKWARDS,
    SEQ_REPEAT,
    STATUS_FRAME_LENGTH,
    SYNC,
    SYNC_FIRST_BYTE,
    TEMP_NO_SENSOR_RAW,
    Frame,
    Hello,
    Sample,
    Status,
    sample_at,
    seq_step,
)


@dataclass(slots=True)
class DecoderCounters:
    """What the decoder saw since it was created; read via ``StreamDecoder.counters``.

    Every byte fed ends up in exactly one place:
    ``bytes_received == bytes in decoded frames + bytes_skipped + StreamDecoder.buffered_bytes``.
    """

    bytes_received: int = 0
    #: Bytes dropped because they were not part of a good frame (garbage, bad frames).
    bytes_skipped: int = 0
    frames_decoded: int = 0
    samples_decoded: int = 0
    statuses_decoded: int = 0
    hellos_decoded: int = 0
    #: Candidates (sync + known type + right N) whose CRC did not match.
    crc_errors: int = 0
    #: Candidates with a sync pair and a known type but the wrong N.
    length_errors: int = 0
    #: Candidates with a sync pair and a type that is not SAMPLE, STATUS or HELLO.
    unknown_types: int = 0
    #: Runs of skipped bytes: how often the decoder lost and searched for sync.
    sync_losses: int = 0
    #: Samples missing according to seq (gaps, see seq_step); continuity restarts at HELLO.
    samples_lost: int = 0
    #: SAMPLEs whose seq was not the expected one (each gap counted once).
    seq_gaps: int = 0
    #: SAMPLEs whose seq repeated the previous one, or stepped back (seq_step): no loss.
    seq_repeats: int = 0
    seq_backwards: int = 0
    #: HELLO frames seen, i.e. board restarts announced.
    board_resets: int = 0


class SampleSink(Protocol):
    """Where a `StreamDecoder` hands the frames it finds, instead of returning them.

    The gateway's sample pipeline is one: it takes whole runs of SAMPLE frames in one
    compiled call (decode, time, convert, estimate), and each report in order, so that
    a HELLO between two samples resets what follows it.
    """

    def take_samples(self, buf: bytes, pos: int, last_seq: int) -> tuple[int, int, int, int, int, int, int]:
        """Take the run of whole, CRC-valid SAMPLE frames from `buf[pos]` on (using
        `sample_at` and `seq_step`): (end, samples, last seq, samples lost, gaps, seq
        repeats, seq backward steps). 0 samples: the frame at `pos` is not a good one."""
        ...

    def on_report(self, frame: Status | Hello) -> None: ...


class StreamDecoder:
    """Turns serial bytes, in any chunking, into frames; never raises on bytes.

    On bad input (no sync, unknown type, wrong N for the type, CRC mismatch) it drops
    one byte and searches for the next sync pair, so every good frame that follows is
    recovered; the only exception is a run of bad bytes that happens to form a
    CRC-valid frame (chance ~2^-16 per candidate), which then swallows what it
    overlaps. At most ``MAX_FRAME_LENGTH - 1`` bytes stay buffered between feeds.

    Decisions depend only on the bytes from a candidate sync to the end of its frame,
    and an incomplete candidate waits for more bytes, so splitting a stream into
    chunks never changes the result.

    With a `sink`, frames go there as they are found (SAMPLE runs to
    `sink.take_samples`, reports to `sink.on_report`) and `feed` returns nothing.
    """

    def __init__(self, sink: SampleSink | None = None) -> None:
        self._pending = b""
        self._counters = DecoderCounters()
        self._last_seq = -1
        self._in_bad_run = False
        self._sink = sink

    @property
    def counters(self) -> DecoderCounters:
        """A snapshot; later feeds do not change it."""
        return replace(self._counters)

    @property
    def live_counters(self) -> DecoderCounters:
        """The decoder's own counters, updated by every feed: read them, never write.

        For a hot loop that reads a counter per sample (a snapshot costs ~10 µs).
        """
        return self._counters

    @property
    def buffered_bytes(self) -> int:
        """Bytes held back for the next feed (an incomplete frame or half a sync pair)."""
        return len(self._pending)

    @property
    def last_seq(self) -> int:
        """seq of the last SAMPLE (or HELLO), −1 before any: what the next gap is counted from."""
        return self._last_seq

    def _skip(self, count: int) -> None:
        counters = self._counters
        counters.bytes_skipped += count
        if not self._in_bad_run:
            counters.sync_losses += 1
            self._in_bad_run = True

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Add bytes from the line; return the frames completed by them, in order
        (none with a sink: they went there)."""
        buf = self._pending + bytes(data) if self._pending else bytes(data)
        counters = self._counters
        counters.bytes_received += len(data)
        size = len(buf)
        frames: list[Frame] = []
        sink = self._sink
        find = buf.find
        crc_hqx = binascii.crc_hqx
        unpack_report = _REPORT_PAYLOAD_CRC.unpack_from
        last_seq = self._last_seq
        samples = reports = hellos = lost_total = gaps = repeats = backwards = 0
        pos = 0

        while True:
            start = find(SYNC, pos)
            if start < 0:
                # No sync pair left; a trailing 0xA5 may be the first half of one
                # that the next feed completes.
                keep_from = size - 1 if size > pos and buf[size - 1] == SYNC_FIRST_BYTE else size
                if keep_from > pos:
                    self._skip(keep_from - pos)
                pos = keep_from
                break
            if start > pos:
                self._skip(start - pos)
                pos = start
            if size - pos < HEADER_LENGTH:
                break
            frame_type = buf[pos + 2]
            length = buf[pos + 3]

            if frame_type == 0x01 and length == 9:  # SAMPLE
                if pos + SAMPLE_FRAME_LENGTH > size:
                    break
                if sink is not None:
                    end, taken, last_seq, lost, run_gaps, run_repeats, run_backwards = sink.take_samples(
                        buf, pos, last_seq)
                else:
                    seq, t1x, t1y, t2, flags = sample_at(buf, pos)
                    taken = seq >= 0
                    if taken:
                        lost, verdict = seq_step(last_seq, seq)
                        run_gaps = 1 if lost else 0
                        run_repeats = 1 if verdict == SEQ_REPEAT else 0
                        run_backwards = 1 if verdict == SEQ_BACKWARDS else 0
                        last_seq = seq
                        frames.append(Sample(seq, t1x, t1y, t2, flags, lost))
                        end = pos + SAMPLE_FRAME_LENGTH
                if not taken:
                    counters.crc_errors += 1
                    self._skip(1)
                    pos += 1
                    continue
                samples += taken
                lost_total += lost
                gaps += run_gaps
                repeats += run_repeats
                backwards += run_backwards
                self._in_bad_run = False
                pos = end
                continue

            if (frame_type == 0x02 or frame_type == 0x03) and length == 14:
                end = pos + STATUS_FRAME_LENGTH
                if end > size:
                    break
                seq, uptime_s, tick_hz, temp, fw_major, fw_minor, crc = unpack_report(buf, pos + 4)
                if crc_hqx(buf[pos + 2 : end - 2], CRC_INITIAL) != crc:
                    counters.crc_errors += 1
                    self._skip(1)
                    pos += 1
                    continue
                if temp == TEMP_NO_SENSOR_RAW:
                    temp = None
                if frame_type == 0x03:
                    report: Frame = Hello(seq, uptime_s, tick_hz, temp, fw_major, fw_minor)
                    hellos += 1
                    # The board restarted: continuity restarts from the HELLO's seq
                    # (0xFFFF), so the next SAMPLE is expected to be seq 0.
                    last_seq = seq
                else:
                    report = Status(seq, uptime_s, tick_hz, temp, fw_major, fw_minor)
                    reports += 1
                if sink is not None:
                    sink.on_report(report)
                else:
                    frames.append(report)
                self._in_bad_run = False
                pos = end
                continue

            if frame_type in PAYLOAD_LENGTH:
                counters.length_errors += 1
            else:
                counters.unknown_types += 1
            self._skip(1)
            pos += 1

        self._pending = buf[pos:]
        self._last_seq = last_seq
        counters.samples_decoded += samples
        counters.statuses_decoded += reports
        counters.hellos_decoded += hellos
        counters.board_resets += hellos
        counters.frames_decoded += samples + reports + hellos
        counters.samples_lost += lost_total
        counters.seq_gaps += gaps
        counters.seq_repeats += repeats
        counters.seq_backwards += backwards
        return frames


def decode_frames(data: bytes | bytearray | memoryview) -> list[Frame]:
    """All complete frames in ``data`` (a fresh decoder; a trailing partial frame is dropped)."""
    return StreamDecoder().feed(data)
