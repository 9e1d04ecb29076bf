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
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.pty_port import PtyPort
from drivers.ucsim_board import BoardSimulatorError, S51Board, S51Result, build_firmware, relay_paced
from gateway.commands.common import add_scenario_options, positive_float, scenario_from_args
from gateway.core.duty_waveform import DutyWaveform, StuckInput, vcd_lines, waveform_from_counts
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate

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
    p.add_argument("--wait-for-reader-s", type=positive_float, default=None,
                   help="start the board's clock after this long even if nobody opened the port "
                        "(default: wait for a reader)")
    add_scenario_options(p)
    return p


def run(args: argparse.Namespace) -> int:
    settings = BoardRunSettings(scenario=scenario_from_args(args), seed=args.seed, board_s=args.seconds,
                                stuck=tuple(args.stuck))
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
                counts = relay_paced(uart, port, args.wait_for_reader_s)
                result = board.wait()
        finally:
            port.close(remove_link=True)
    for line in budget_lines(result, sizes):
        print(line, file=sys.stderr)
    print(f"sent {counts['samples']} samples, {counts['bytes']} bytes", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return run(args)
    except BoardSimulatorError as err:
        print(f"board-in-ucsim: {err}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
