"""The board's firmware run in ucsim's s51 (a cycle-accurate 8051 simulator).

The edge of `scripts/board-in-ucsim` and of the firmware tests: build `firmware/` with
SDCC, run s51 on it with a value change dump replayed onto the duty-cycle pins, take
its UART bytes (through a named pipe: s51's TCP serial output drops bytes under load, a
pipe does not) and its CPU time report, and relay the bytes to a pty paced to board
time.

How s51 is driven (ucsim 0.6.4, Debian's sdcc-ucsim): its command console reads a
script (`-C`); the run stops at breakpoints on the INT0 vector whose hit count is a
number of XOUT falling edges — the board's own periods, since a stop by simulated time
(`step N ms`) does not return in this version. Its `timer get` reports the clocks
simulated, in interrupts and in the CPU's idle mode; the firmware idles in idle mode, so
the idle share is s51's count, not an estimate.
"""
from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from drivers.board_protocol import CRC_LENGTH, HEADER_LENGTH, PAYLOAD_LENGTH, SYNC, sample_at
from drivers.errors import DriverError
from drivers.pty_port import PtyPort

# An 80C52: the CMOS part, which has the idle mode the firmware sleeps in (s51's "8052"
# is the HMOS part, whose PCON has no idle bit).
S51_CPU = "C52"
XTAL_HZ = 11_059_200
CLOCKS_PER_MACHINE_CYCLE = 12
INT0_VECTOR = 0x0003
DEFAULT_TICK_HZ = XTAL_HZ // CLOCKS_PER_MACHINE_CYCLE


class BoardSimulatorError(DriverError):
    """The tools for the simulated board are missing or failed (one line: what and where)."""


def require_tool(name: str, package: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise BoardSimulatorError(f"{name} not found: install the Debian package {package} "
                                  "(scripts/setup.sh --test does)")
    return path


def build_firmware(firmware_dir: Path, build_dir: Path) -> tuple[Path, str]:
    """`make` in firmware/ into build_dir; the .ihx and what the Makefile printed (sizes)."""
    require_tool("sdcc", "sdcc")
    result = subprocess.run(["make", "--no-print-directory", "-C", str(firmware_dir), f"BUILD={build_dir}"],
                            capture_output=True, text=True)
    if result.returncode != 0:
        tail = (result.stderr or result.stdout).strip().splitlines()[-1:] or ["(no output)"]
        raise BoardSimulatorError(f"building {firmware_dir} failed: {tail[0]}")
    sizes = "\n".join(line for line in result.stdout.splitlines() if line.startswith(("code:", "data:")))
    return Path(build_dir) / "board.ihx", sizes


@dataclass(frozen=True)
class CpuTime:
    """s51's clock counters (oscillator clocks): all, in interrupt routines, in idle mode."""

    clocks: int
    isr_clocks: int
    idle_clocks: int

    def __sub__(self, other: CpuTime) -> CpuTime:
        return CpuTime(self.clocks - other.clocks, self.isr_clocks - other.isr_clocks,
                       self.idle_clocks - other.idle_clocks)

    @property
    def idle_share(self) -> float:
        return self.idle_clocks / self.clocks

    @property
    def isr_share(self) -> float:
        return self.isr_clocks / self.clocks

    @property
    def main_share(self) -> float:
        return 1.0 - self.idle_share - self.isr_share

    def busy_cycles_per(self, periods: int) -> float:
        return (self.clocks - self.idle_clocks) / CLOCKS_PER_MACHINE_CYCLE / periods


_TIMER_LINE = re.compile(r'timer #\d+\("(\w+)"\).*\((\d+) clks\)')


def parse_timer_reports(console_text: str) -> list[CpuTime]:
    """Each `timer get` answer in s51's console output, in order."""
    reports, current = [], {}
    for name, clocks in _TIMER_LINE.findall(console_text):
        current[name] = int(clocks)
        if name == "halt":
            reports.append(CpuTime(current["time"], current["isr"], current["idle"]))
            current = {}
    return reports


def s51_script(ihx: Path, vcd: Path, warmup_periods: int, measured_periods: int) -> str:
    """Load, replay the pins, run `warmup_periods` X periods (start-up and the first T2
    measurement), report, run `measured_periods` more, report, quit."""
    if warmup_periods < 1 or measured_periods < 1:
        raise ValueError("both spans need at least one period")
    return "\n".join([
        f'load "{ihx}"',
        f'set hw vcd[0] input "{vcd}"',
        "set hw vcd[0] start",
        f"break 0x{INT0_VECTOR:04x} {warmup_periods}",
        "run",
        "timer get",
        "delete 1",
        f"break 0x{INT0_VECTOR:04x} {measured_periods}",
        "run",
        "timer get",
        "quit",
        "",
    ])


@dataclass(frozen=True)
class S51Result:
    warmup: CpuTime
    measured: CpuTime  # the measured span only
    measured_periods: int
    console: str


class S51Board:
    """s51 running the firmware: UART bytes into `uart_out` (a file, or a named pipe that
    someone reads), the console into memory. A context manager; `wait()` for the result."""

    def __init__(self, ihx: Path, vcd: Path, uart_out: Path, script_path: Path,
                 warmup_periods: int, measured_periods: int):
        self.measured_periods = measured_periods
        script_path.write_text(s51_script(ihx, vcd, warmup_periods, measured_periods), encoding="utf-8")
        s51 = require_tool("s51", "sdcc-ucsim")
        self.process = subprocess.Popen(
            [s51, "-b", "-t", S51_CPU, "-X", str(XTAL_HZ), "-S", f"out={uart_out}", "-C", str(script_path)],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )

    def wait(self, timeout_s: float | None = None) -> S51Result:
        console, _ = self.process.communicate(timeout=timeout_s)
        reports = parse_timer_reports(console)
        if self.process.returncode != 0 or len(reports) != 2:
            last = console.strip().splitlines()[-1:] or ["(no output)"]
            raise BoardSimulatorError(f"s51 ended (exit {self.process.returncode}) without its two time "
                                      f"reports; its last line: {last[0]}")
        return S51Result(reports[0], reports[1] - reports[0], self.measured_periods, console)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()

    def __enter__(self) -> S51Board:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


# --- pacing to board time -----------------------------------------------------------------


class BoardTimePacer:
    """Cuts the board's byte stream after each SAMPLE frame and gives each piece its board
    time: the end of that sample's period, the sum of the T2 sent so far (the protocol's
    clock). Bytes that are not a good SAMPLE frame travel with the next one, unchanged."""

    def __init__(self, tick_hz: float = DEFAULT_TICK_HZ):
        self.tick_hz = tick_hz
        self.board_ticks = 0
        self._buf = bytearray()
        self._scan = 0  # bytes before this are known to hold no SAMPLE start

    def feed(self, data: bytes) -> Iterator[tuple[float, bytes]]:
        """(board time s, bytes due then) for every SAMPLE frame completed by `data`."""
        self._buf += data
        buf = self._buf
        pos = self._scan
        sample_length = HEADER_LENGTH + PAYLOAD_LENGTH[1] + CRC_LENGTH
        while True:
            pos = buf.find(SYNC, pos)
            if pos < 0 or pos + sample_length > len(buf):
                break
            seq, _t1x, _t1y, t2, _flags = sample_at(buf, pos)
            if seq < 0:
                pos += 1
                continue
            end = pos + sample_length
            self.board_ticks += t2
            yield self.board_ticks / self.tick_hz, bytes(buf[:end])
            del buf[:end]
            pos = 0
        self._scan = max(0, len(buf) - 1) if pos < 0 else pos

    def rest(self) -> bytes:
        """What is left (the bytes after the last SAMPLE frame: a STATUS, a partial frame)."""
        out = bytes(self._buf)
        self._buf.clear()
        self._scan = 0
        return out


def read_pipe(path: Path, chunks: list[bytes], done: threading.Event, lock: threading.Lock) -> None:
    """Read a named pipe to its end (the writer's exit) into `chunks` (a thread's body)."""
    try:
        with open(path, "rb", buffering=0) as pipe:
            while True:
                data = pipe.read(65536)
                if not data:
                    break
                with lock:
                    chunks.append(data)
    finally:
        done.set()


def _release_pipe_reader(path: Path) -> None:
    """A reader still blocked opening the pipe (its writer died before opening it) gets
    its end of file: open the write end once and close it."""
    with contextlib.suppress(OSError):  # no reader waiting in open(): nothing to release
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))


def relay_paced(pipe_path: Path, port: PtyPort, wait_for_reader_s: float | None = None,
                writer_alive=lambda: True, clock=time.monotonic, sleep=time.sleep) -> dict[str, int]:
    """Read the board's bytes from the pipe as s51 writes them (s51 runs ahead of real
    time) and write each SAMPLE to the pty when its period ends in board time, the clock
    starting when a reader opens the pty. Ends at the pipe's end of file, also when the
    writer (`writer_alive` false) died without opening it. Returns byte and sample counts."""
    chunks: list[bytes] = []
    lock = threading.Lock()
    done = threading.Event()
    reader = threading.Thread(target=read_pipe, args=(pipe_path, chunks, done, lock), daemon=True)
    reader.start()
    port.wait_for_reader(wait_for_reader_s)
    start = clock()
    pacer = BoardTimePacer()
    counts = {"bytes": 0, "samples": 0}
    while True:
        with lock:
            new, chunks[:] = list(chunks), []
        if not new:
            if done.is_set():
                with lock:
                    if chunks:
                        continue
                break
            if not writer_alive():
                _release_pipe_reader(pipe_path)
            sleep(0.005)
            continue
        for data in new:
            for due_s, piece in pacer.feed(data):
                delay = start + due_s - clock()
                if delay > 0:
                    sleep(delay)
                # a reader that went away must not stall the relay: then the bytes
                # are lost as on a line with nobody listening
                counts["bytes"] += port.write(piece, block=port.has_reader())
                counts["samples"] += 1
    counts["bytes"] += port.write(pacer.rest(), block=port.has_reader())
    reader.join()
    return counts
