"""scripts/board-in-ucsim: the real firmware on a simulated 8052, served on a pty.

Builds firmware/ with SDCC, makes the ADXL202's two duty-cycle waveforms from the
project's simulator (the scenarios of `adxlgw emulate`), runs s51 with them on INT0/INT1,
and relays the firmware's UART bytes to a pty at --link, paced to board time, so that
`adxlgw record --port PATH` and `adxlgw run --serial PATH` read it as they read a board.
At the end it prints the CPU budget s51 measured (stderr).

Exit codes: 0 done, 2 bad arguments, 3 the simulator or compiler is missing or failed,
130 interrupted.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.board_decoder import DecoderCounters, StreamDecoder
from drivers.board_protocol import Sample
from drivers.pty_port import PtyPort
from drivers.ucsim_board import BoardSimulatorError, S51Board, S51Result, build_firmware, relay_paced
from gateway.commands.common import add_scenario_options, positive_float, scenario_from_args
from gateway.core.conversion import AxisCalibration, acceleration_mps2, axis_valid, lost_before_from_seq, sample_times_s
from gateway.core.duty_waveform import DutyWaveform, StuckInput, vcd_lines, waveform_from_counts
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import rest_intervals
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import SimulatedRun, simulate

REPO = Path(__file__).resolve().parents[1]
FIRMWARE_DIR = REPO / "firmware"
# The pins stay low this long before the first period, so the firmware has set up its
# timers before the first edge (its start-up takes well under a millisecond).
LEAD_S = 0.001
# s51 first runs this many X periods (start-up and the first 34-period T2 measurement),
# then the measured span: the CPU budget is of the steady state.
WARMUP_PERIODS = 100
# The waveform runs this many periods beyond the board's last one, so s51 never outruns it.
SPARE_PERIODS = 20


@dataclass(frozen=True)
class BoardRunSettings:
    scenario: ScenarioSettings = ScenarioSettings()
    sensor: SensorParams = SensorParams()
    seed: int = 0
    board_s: float = 60.0
    stuck: tuple[StuckInput, ...] = ()

    @property
    def periods(self) -> int:
        return int(self.board_s / self.sensor.t2_s)

    @property
    def waveform_periods(self) -> int:
        """The board's periods, the spare, and the periods X spends stuck: s51's run ends
        at a count of X falling edges, and a stuck X has none."""
        stuck_x_s = sum(s.duration_s for s in self.stuck if s.axis == "x")
        return self.periods + SPARE_PERIODS + int(np.ceil(stuck_x_s / self.sensor.t2_s))


def scenario_waveform(settings: BoardRunSettings) -> DutyWaveform:
    """The scenario's counts for the whole run — repeated as `adxlgw emulate --loop` does
    (seed + block for each repeat) — as the pin waveform."""
    profile = build_profile(settings.scenario)
    need = settings.waveform_periods
    t1x, t1y, t2 = [], [], []
    block = 0
    while sum(a.size for a in t1x) < need:
        run = simulate(profile, settings.sensor, seed=settings.seed + block)
        t1x.append(run.t1x)
        t1y.append(run.t1y)
        t2.append(run.t2)
        block += 1
    return waveform_from_counts(run.tick_hz, np.concatenate(t1x)[:need], np.concatenate(t1y)[:need],
                                np.concatenate(t2)[:need], lead_s=LEAD_S)


def write_vcd(wave: DutyWaveform, stuck: tuple[StuckInput, ...], path: Path) -> None:
    with open(path, "w", encoding="ascii") as f:
        for line in vcd_lines(wave, stuck):
            f.write(line)
            f.write("\n")


@dataclass(frozen=True)
class BoardRecord:
    """A finished run of the firmware in s51: its UART bytes, its CPU report, the pins."""

    uart_bytes: bytes
    s51: S51Result
    waveform: DutyWaveform
    sizes: str


def run_board_to_file(settings: BoardRunSettings, work: Path, timeout_s: float | None = None) -> BoardRecord:
    """Build, run s51 to the end of the settings' board time with the UART into a file,
    and return what the board sent (no pacing: for tests and benchmarks)."""
    measured = settings.periods - WARMUP_PERIODS
    if measured < 1:
        raise ValueError(f"board_s {settings.board_s}: shorter than the start-up span")
    ihx, sizes = build_firmware(FIRMWARE_DIR, work / "build")
    wave = scenario_waveform(settings)
    write_vcd(wave, settings.stuck, work / "pins.vcd")
    uart = work / "uart.bin"
    uart.touch()
    with S51Board(ihx, work / "pins.vcd", uart, work / "s51.cmd", WARMUP_PERIODS, measured) as board:
        result = board.wait(timeout_s)
    return BoardRecord(uart.read_bytes(), result, wave, sizes)


# --- checks of the firmware's stream against the waveform it was given ------------------


@dataclass(frozen=True)
class BoardStream:
    """The SAMPLE frames of a byte stream as columns, with the decoder's counters."""

    frames: list
    counters: DecoderCounters
    seq: np.ndarray
    t1x: np.ndarray
    t1y: np.ndarray
    t2: np.ndarray
    flags: np.ndarray

    def __len__(self) -> int:
        return int(self.seq.size)


def decode_board_bytes(data: bytes) -> BoardStream:
    decoder = StreamDecoder()
    frames = decoder.feed(data)
    samples = [f for f in frames if isinstance(f, Sample)]

    def column(name):
        return np.array([getattr(s, name) for s in samples], dtype=np.int64)

    return BoardStream(frames, decoder.counters, column("seq"), column("t1x_ticks"), column("t1y_ticks"),
                       column("t2_ticks"), column("flags"))


def first_period(stream: BoardStream, wave: DutyWaveform, search: int = 200) -> int:
    """The waveform period of the firmware's first sample (its start-up takes a few tens
    of periods): the offset where the X counts agree best over the whole stream."""
    ok = (stream.flags & 1) == 0
    n = min(len(stream), len(wave) - search)
    errors = [np.mean(np.abs(stream.t1x[:n][ok[:n]] - wave.t1x_ticks[p:p + n][ok[:n]])) for p in range(search)]
    return int(np.argmin(errors))


@dataclass(frozen=True)
class TimingCheck:
    """The firmware's counts against the waveform's, in ticks (worst over the stream)."""

    first_period: int
    samples: int
    worst_t1x_ticks: float
    worst_t1y_ticks: float
    worst_t2_ticks: float
    x_unmeasured: int  # samples with X's flag
    y_unmeasured: int  # with Y's: the T2 spans (32 of every 1024 periods) and timeouts
    clock_error_ticks: int  # the sum of the T2 sent less the waveform's over the same periods


def timing_against_waveform(stream: BoardStream, wave: DutyWaveform) -> TimingCheck:
    p0 = first_period(stream, wave)
    n = len(stream)
    x_ok = (stream.flags & 1) == 0
    y_ok = (stream.flags & 2) == 0
    err_x = (stream.t1x - wave.t1x_ticks[p0:p0 + n])[x_ok]
    err_y = (stream.t1y - wave.t1y_ticks[p0:p0 + n])[y_ok]
    err_t2 = stream.t2 - wave.t2_ticks[p0:p0 + n]

    def worst(err):
        return float(np.max(np.abs(err))) if err.size else float("nan")

    return TimingCheck(p0, n, worst(err_x), worst(err_y), worst(err_t2), int(np.count_nonzero(~x_ok)),
                       int(np.count_nonzero(~y_ok)), int(stream.t2.sum() - wave.t2_ticks[p0:p0 + n].sum()))


def realtime_position_m(t2, t1x, flags, seq, tick_hz: float) -> np.ndarray:
    """The gateway's causal estimate (`adxlgw estimate --method realtime` on a raw
    recording: the sensor model's settings) of X's position for each sample."""
    lost = lost_before_from_seq(seq)
    t = sample_times_s(t2, tick_hz, lost)
    acc = acceleration_mps2(t1x, t2, AxisCalibration())
    valid = axis_valid(flags, t1x, t2, "x")
    return estimate_series(t, acc, valid, method="realtime", settings=from_sensor_model(SensorParams()),
                           lost_before=lost).pos_m


@dataclass(frozen=True)
class StopCheck:
    stop: int  # 1 = the first stop after the initial rest
    firmware_m: float
    emulator_m: float
    truth_m: float


def position_at_stop(stream: BoardStream, wave: DutyWaveform, truth: SimulatedRun, stop: int) -> StopCheck:
    """Position at the end of the `stop`-th stop (or the stream's end, if sooner), from the
    firmware's stream and from the emulator's (the simulated counts from period 0: what
    `adxlgw emulate` sends), both by the gateway's realtime estimate."""
    p0 = first_period(stream, wave)
    start, end = rest_intervals(truth.t_s, truth.ref_vel_mps)[stop]
    at = min(end - 1, p0 + len(stream) - 1)
    if at <= start:
        raise ValueError(f"the stream ends before stop {stop}")
    n = at + 1
    emulator = realtime_position_m(truth.t2[:n], truth.t1x[:n], truth.flags[:n], truth.seq[:n], truth.tick_hz)
    firmware = realtime_position_m(stream.t2, stream.t1x, stream.flags, stream.seq, truth.tick_hz)
    return StopCheck(stop, float(firmware[at - p0]), float(emulator[at]), float(truth.ref_pos_m[at]))


def budget_lines(result: S51Result, sizes: str) -> list[str]:
    m = result.measured
    cycles_per_period = m.clocks / 12 / result.measured_periods
    return [
        sizes,
        f"CPU over {result.measured_periods} periods ({m.clocks / 11_059_200:.3f} s of board time, "
        f"after {WARMUP_PERIODS} of start-up): idle {100 * m.idle_share:.1f} %, interrupts "
        f"{100 * m.isr_share:.1f} %, main loop {100 * m.main_share:.1f} %; busy "
        f"{m.busy_cycles_per(result.measured_periods):.0f} of {cycles_per_period:.0f} machine cycles per sample",
    ]


def parse_stuck(text: str) -> StuckInput:
    try:
        axis, start, duration, level = text.split(":")
        return StuckInput(axis, float(start), float(duration), int(level))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"--stuck {text!r}: expected AXIS:START_S:DURATION_S:LEVEL "
                                         f"(e.g. x:5:0.2:0) — {err}") from err


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="board-in-ucsim",
        description="Run the board's firmware (firmware/) in ucsim's s51 on the ADXL202 waveforms of a "
                    "simulated run and serve its serial output on a pty, paced to board time. Prints the "
                    "pty's path on the first line of stdout and the CPU budget on stderr at the end.",
    )
    p.add_argument("--link", required=True, help="make this path a symlink to the pty (the port to read)")
    p.add_argument("--seconds", type=positive_float, default=60.0, help="board time to run, s (default: 60)")
    p.add_argument("--stuck", type=parse_stuck, action="append", default=[],
                   help="hold an input: AXIS:START_S:DURATION_S:LEVEL (x or y, 0 or 1); repeatable")
    p.add_argument("--t2-error-frac", type=float, default=SensorParams().t2_error_frac,
                   help="the part's T2 against RSET/125 MΩ (default: the simulator's "
                        f"{SensorParams().t2_error_frac:+g}; 0: exactly 2.000 ms, 500 samples/s)")
    p.add_argument("--linger", type=positive_float, default=1.0,
                   help="keep the port open this long after the last frame, s, so the reader gets it (default: 1)")
    p.add_argument("--wait-for-reader-s", type=positive_float, default=None,
                   help="start the board's clock after this long even if nobody opened the port "
                        "(default: wait for a reader)")
    add_scenario_options(p)
    return p


def run(args: argparse.Namespace) -> int:
    if not -0.5 < args.t2_error_frac < 0.5:
        print(f"board-in-ucsim: --t2-error-frac {args.t2_error_frac}: expected within ±0.5", file=sys.stderr)
        return 2
    settings = BoardRunSettings(scenario=scenario_from_args(args), seed=args.seed, board_s=args.seconds,
                                stuck=tuple(args.stuck), sensor=SensorParams(t2_error_frac=args.t2_error_frac))
    measured = settings.periods - WARMUP_PERIODS
    if measured < 1:
        print(f"board-in-ucsim: --seconds {args.seconds}: too short (at least "
              f"{(WARMUP_PERIODS + 1) * settings.sensor.t2_s:.2f} s)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="board-in-ucsim.") as tmp:
        work = Path(tmp)
        ihx, sizes = build_firmware(FIRMWARE_DIR, work / "build")
        write_vcd(scenario_waveform(settings), settings.stuck, work / "pins.vcd")
        uart = work / "uart.pipe"
        os.mkfifo(uart)
        port = PtyPort(args.link)
        print(port.path, flush=True)
        try:
            with S51Board(ihx, work / "pins.vcd", uart, work / "s51.cmd", WARMUP_PERIODS, measured) as board:
                counts = relay_paced(uart, port, args.wait_for_reader_s,
                                     writer_alive=lambda: board.process.poll() is None)
                result = board.wait()
            # closing a pty drops what its reader has not read yet
            time.sleep(args.linger)
        finally:
            port.close(remove_link=True)
    for line in budget_lines(result, sizes):
        print(line, file=sys.stderr)
    print(f"sent {counts['samples']} samples, {counts['bytes']} bytes", file=sys.stderr)
    return 0


def _interrupt(_signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM ends as Ctrl-C does: s51 stopped, the pty and its link removed


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return run(args)
    except BoardSimulatorError as err:
        print(f"board-in-ucsim: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
