"""adxlgw record: read a board (or the emulator) and write a raw recording."""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from drivers.board_decoder import StreamDecoder
from drivers.board_protocol import Hello, Sample, Status
from drivers.errors import SerialPortError
from drivers.serial_port import SerialSettings, reconnect_delays_s
from drivers.serial_source import SerialSource
from gateway.commands.common import StopOnSignal, positive_float
from gateway.errors import DeviceError
from gateway.offline.recording import RecordingWriter

log = logging.getLogger("adxlgw.record")

COLUMNS = ["seq", "t1x", "t1y", "t2", "flags", "t_host_s", "temp_c"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "record",
        help="read the board's serial stream and write a raw recording",
        description="Read a board from a serial port (device path or pyserial URL), decode its frames "
                    "and write every SAMPLE as a row of a raw recording, with the tick rate the board "
                    "reports. A board reset (HELLO) mid-recording starts a new file FILE.resetN.csv, "
                    "since seq and time restart with it. On exit it prints the counters.",
    )
    p.add_argument("--port", required=True, help="serial device or pyserial URL")
    p.add_argument("--out", required=True, help="recording to write: CSV (each row on disk as it comes), or "
                                                "Parquet when it ends in .parquet (the file appears at the end)")
    p.add_argument("--duration", type=positive_float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--once", action="store_true",
                   help="exit (code 3) when the port cannot be opened or is lost, instead of retrying")
    p.add_argument("--tick-hz", type=positive_float,
                   help="timer rate to assume if the board never reports one (it reports it in STATUS/HELLO)")
    p.add_argument("--baudrate", type=int, default=115200, help="line speed (default: 115200)")
    p.set_defaults(run=run)


class _Segments:
    """One file per continuous board session (a HELLO restarts seq and time)."""

    def __init__(self, out: str, port: str):
        self.out = Path(out)
        self.port = port
        self.index = 0
        self.writer: RecordingWriter | None = None
        self.paths: list[str] = []
        self.rows_total = 0

    def path(self) -> Path:
        if self.index == 0:
            return self.out
        return self.out.with_name(f"{self.out.stem}.reset{self.index}{self.out.suffix}")

    def open(self, tick_hz: float) -> None:
        path = self.path()
        meta = {"tick_hz": f"{tick_hz:g}", "source": "board", "axis": "x", "port": self.port,
                "started_unix_s": f"{time.time():.3f}"}
        self.writer = RecordingWriter(path, meta, COLUMNS)
        self.paths.append(str(path))

    def next(self) -> None:
        self.close()
        self.index += 1

    def write(self, row: dict) -> None:
        self.writer.write_row(row)
        self.rows_total += 1

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def _open_with_retry(source: SerialSource, once: bool, should_stop) -> bool:
    delays = reconnect_delays_s(source.settings)
    while not should_stop():
        try:
            source.open()
            return True
        except SerialPortError as err:
            if once:
                raise DeviceError(str(err)) from err
            delay = next(delays)
            log.warning("%s; retrying in %.1f s", err, delay)
            time.sleep(delay)
    return False


class _Session:
    """The board's frames → rows in files. Samples wait until the board tells its tick rate
    (STATUS or HELLO; `assumed_tick_hz` when it never does); a board reset (HELLO) or a new
    tick rate starts a new file."""

    def __init__(self, segments: _Segments, assumed_tick_hz: float | None) -> None:
        self.segments = segments
        self._assumed_tick_hz = assumed_tick_hz
        self.tick_hz: float | None = None
        self._temp_c: float | None = None
        self.pending: list[dict] = []  # samples before the board told its tick rate

    def take(self, frame: object, t_host_s: float) -> None:
        segments = self.segments
        if isinstance(frame, Sample):
            row = {"seq": frame.seq, "t1x": frame.t1x_ticks, "t1y": frame.t1y_ticks, "t2": frame.t2_ticks,
                   "flags": frame.flags, "t_host_s": round(t_host_s, 6), "temp_c": self._temp_c}
            if segments.writer is None:
                self.pending.append(row)
            else:
                segments.write(row)
        elif isinstance(frame, (Status, Hello)):
            if isinstance(frame, Hello) and (segments.rows_total or self.pending) and segments.writer is not None:
                log.warning("board reset (HELLO): continuing in a new file")
                segments.next()
            elif segments.writer is not None and frame.tick_hz != self.tick_hz:
                log.warning("board changed its tick rate %s → %s: new file", self.tick_hz, frame.tick_hz)
                segments.next()
            self.tick_hz = frame.tick_hz
            self._temp_c = frame.temp_c

    def settle(self) -> None:
        """Opens the file once the tick rate is known (writing the samples that waited) and
        puts what was written on disk."""
        segments = self.segments
        if segments.writer is None and self.tick_hz is None and self._assumed_tick_hz and self.pending:
            self.tick_hz = self._assumed_tick_hz
        if segments.writer is None and self.tick_hz is not None:
            segments.open(self.tick_hz)
            for row in self.pending:
                segments.write(row)
            self.pending.clear()
        if segments.writer is not None:
            segments.writer.flush()


def _record(source: SerialSource, decoder: StreamDecoder, session: _Session, started: float, should_stop) -> int:
    """Reads and writes until told to stop; the exit code (DeviceError's when the port is
    lost with --once)."""
    while not should_stop():
        try:
            data = source.read(timeout_s=0.1)
        except SerialPortError as err:  # only with --once: the port is gone
            log.error("%s", err)
            return DeviceError.exit_code
        if not data:
            continue
        t_host_s = time.monotonic() - started
        for frame in decoder.feed(data):
            session.take(frame, t_host_s)
        session.settle()
    return 0


def _report(decoder: StreamDecoder, source: SerialSource, segments: _Segments) -> None:
    c = decoder.counters
    state = source.state
    print(
        f"record: {segments.rows_total} samples written to {', '.join(segments.paths) or 'no file'}; "
        f"frames {c.frames_decoded} (samples {c.samples_decoded}, status {c.statuses_decoded}, "
        f"hello {c.hellos_decoded}); crc errors {c.crc_errors}; bytes skipped {c.bytes_skipped}; "
        f"samples lost {c.samples_lost}; board resets {c.board_resets}; "
        f"port losses {state.losses}, reconnects {state.reconnects}",
        file=sys.stderr,
    )


def run(args: argparse.Namespace) -> int:
    stop = StopOnSignal()
    started = time.monotonic()

    def should_stop() -> bool:
        return stop or (args.duration is not None and time.monotonic() - started >= args.duration)

    source = SerialSource(SerialSettings(port=args.port, baudrate=args.baudrate, reconnect=not args.once))
    decoder = StreamDecoder()
    session = _Session(_Segments(args.out, args.port), args.tick_hz)
    exit_code = 0
    try:
        if not _open_with_retry(source, args.once, should_stop):
            return 0
        log.info("recording %s → %s", args.port, args.out)
        exit_code = _record(source, decoder, session, started, should_stop)
    finally:
        session.segments.close()
        source.close()
        _report(decoder, source, session.segments)
    if session.pending:
        print(f"adxlgw record: error: {len(session.pending)} samples not written: the board never reported its "
              f"tick rate (no STATUS or HELLO); pass --tick-hz", file=sys.stderr)
        return DeviceError.exit_code
    return exit_code
