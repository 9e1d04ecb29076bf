"""The firmware in s51: its CPU budget, its timing, the gateway's position from its stream,
and `adxlgw record` reading it through a pty (docs/board-link.md, "The firmware").

    .venv/bin/python -m benchmarks.daemon.board_in_ucsim_benchmark [--seeds 0 1 2] [--pty-seconds 60]

Part 1, per seed: the paper scenario (16.9 s of board time) run to a file; the worst
timing error of T1x, T1y, T2 against the waveform, the board clock's error, the position
at the 10th stop from the firmware's stream and from the emulator's, and s51's CPU
shares over the steady state. Part 2: scripts/board-in-ucsim for --pty-seconds of board
time read by `adxlgw record --once` on the pty: its counters, and the samples per second
of board time beside the board's own rate (1/T2). s51's counts are simulated cycles,
the same on any host; only part 2's wall time depends on the machine.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import harness
from gateway.board_in_ucsim import (
    BoardRunSettings,
    budget_lines,
    decode_board_bytes,
    position_at_stop,
    run_board_to_file,
    timing_against_waveform,
)
from gateway.core.scenarios import build_profile
from gateway.core.simulator import simulate
from gateway.offline.recording import read_recording

ROOT = Path(__file__).resolve().parents[2]
TICK_HZ = 921_600


def firmware_on_paper(seed: int) -> None:
    settings = BoardRunSettings(seed=seed, board_s=build_profile(BoardRunSettings().scenario).duration_s - 0.1)
    with tempfile.TemporaryDirectory() as tmp:
        record = run_board_to_file(settings, Path(tmp), timeout_s=1800)
    stream = decode_board_bytes(record.uart_bytes)
    c = stream.counters
    timing = timing_against_waveform(stream, record.waveform)
    truth = simulate(build_profile(settings.scenario), settings.sensor, seed=seed)
    stop = position_at_stop(stream, record.waveform, truth, stop=10)
    print(f"seed {seed}: {len(stream)} samples, crc errors {c.crc_errors}, lost {c.samples_lost}, "
          f"bytes skipped {c.bytes_skipped}")
    print(f"  worst |error| ticks: t1x {timing.worst_t1x_ticks:.0f}, t1y {timing.worst_t1y_ticks:.0f} "
          f"({timing.y_unmeasured} Y samples not measured: T2 spans), t2 {timing.worst_t2_ticks:.0f}; "
          f"board clock {timing.clock_error_ticks:+d} ticks over {len(stream)} periods")
    print(f"  10th stop: firmware {1000 * stop.firmware_m:.3f} mm, emulator {1000 * stop.emulator_m:.3f} mm "
          f"(difference {1000 * (stop.firmware_m - stop.emulator_m):+.3f} mm), truth {1000 * stop.truth_m:.3f} mm")
    for line in budget_lines(record.s51, record.sizes)[1:]:
        print("  " + line)


def record_through_pty(seconds: float, t2_error_frac: float | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        link, out = Path(tmp) / "board", Path(tmp) / "rec.csv"
        part = [] if t2_error_frac is None else ["--t2-error-frac", str(t2_error_frac)]
        board = subprocess.Popen([str(ROOT / "scripts/board-in-ucsim"), "--link", str(link), "--seconds", str(seconds),
                                  *part],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            board.stdout.readline()
            rec = subprocess.run([sys.executable, "-m", "gateway.cli", "record", "--port", str(link), "--out", str(out),
                                  "--once"], capture_output=True, text=True, timeout=seconds * 10 + 600)
            _, board_err = board.communicate(timeout=600)
        finally:
            board.kill()
        recording = read_recording(out)
    c = recording.columns
    board_s = c["t2"].sum() / TICK_HZ
    host_s = c["t_host_s"][-1] - c["t_host_s"][0]
    summary = [line for line in rec.stderr.splitlines() if line.startswith("record:")]
    part = "the default part" if t2_error_frac is None else f"--t2-error-frac {t2_error_frac:g}"
    print(f"pty, {seconds:g} s of board time, {part}: {summary[0] if summary else rec.stderr.strip()}")
    print(f"  {len(recording)} samples over {board_s:.3f} s of board time: {len(recording) / board_s:.2f} samples/s "
          f"(the board's rate 1/T2: {TICK_HZ / c['t2'].mean():.2f}); "
          f"host arrivals {(len(recording) - 1) / host_s:.2f}/s; "
          f"seq steps all +1: {bool(np.all(np.diff(c['seq']) == 1))}")
    for line in board_err.strip().splitlines():
        print("  board: " + line)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    p.add_argument("--pty-seconds", type=float, default=60.0, help="0: skip part 2")
    p.add_argument("--t2-error-frac", type=lambda v: None if v == "default" else float(v), nargs="*",
                   default=[None], help="part 2 once per value: the part's T2 error, or 'default' (the simulator's)")
    args = p.parse_args()
    harness.stamp("benchmarks.daemon.board_in_ucsim_benchmark")
    for seed in args.seeds:
        firmware_on_paper(seed)
    if args.pty_seconds > 0:
        for frac in args.t2_error_frac:
            record_through_pty(args.pty_seconds, frac)


if __name__ == "__main__":
    main()
