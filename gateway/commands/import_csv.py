"""adxlgw import: another logger's CSV → a recording in the acceleration form.

Sample times come either from a trusted column (`--time-col`, the sensor's own clock) or
are recovered from the PC's arrival times (`--arrival-col`, gateway/core/retiming.py).
Reference columns and the machine's standstill hint are carried through row by row, so
a logger file with a reference becomes a scored recording in one command. Reading the
file's rows: foreign_csv.py.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from gateway.commands.common import positive_float
from gateway.commands.foreign_csv import _Skipped, _wanted, foreign_blocks, read_foreign
from gateway.core.retiming import Retiming, RetimingError, RetimingSettings, on_sample_clock, retime, timing_error
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.errors import RecordingError
from gateway.offline.recording import (
    FORMAT_ID,
    HINT_COLUMN,
    ColumnWriter,
    check_output,
    write_recording,
)

UNIT_SCALES = {"g": STANDARD_GRAVITY_MPS2, "mps2": 1.0, "mg": STANDARD_GRAVITY_MPS2 / 1000}
TIME_SCALES = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
LENGTH_SCALES = {"m": 1.0, "mm": 1e-3}
# role → (option, recording column); the reference is along the measured axis, in SI
REFERENCE_ROLES = {"ref_pos": "ref_pos_m", "ref_vel": "ref_vel_mps", "ref_acc": "ref_acc_mps2"}


#: Below this the rows cannot follow a motion: the paper's strokes last 0.4 s, the robot's
#: moves about a second. What it catches: a millisecond time column read as seconds
#: (1000× too slow: 0.5 samples/s for a 500 Hz log).
MIN_RATE_HZ = 1.0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "import",
        help="convert another logger's CSV into a recording (acceleration form)",
        description="Read a foreign CSV, take the sample times (a sensor-clock column, or the PC's "
                    "arrival times re-timed onto the sensor's regular clock), one or two acceleration "
                    "columns, and optionally a reference and a standstill hint; write a recording in "
                    "the acceleration form. Rows whose time or acceleration cell is empty are skipped "
                    "and counted (e.g. interleaved rows of another kind).",
    )
    p.add_argument("foreign", metavar="FOREIGN.csv")
    when = p.add_mutually_exclusive_group(required=True)
    when.add_argument("--time-col", help="column with the sample time on the sensor's clock")
    when.add_argument("--arrival-col",
                      help="column with the time the PC received each sample: the sample times are "
                           "recovered from it (a regular sensor clock, lost samples found as gaps) and "
                           "it is kept as t_host_s")
    p.add_argument("--nominal-rate-hz", type=positive_float,
                   help="with --arrival-col: the sensor's configured sample rate, if known; the period "
                        "is then sought within ±10 %% of it (needed when a start-up backlog is most of "
                        "the file: the arrivals alone cannot tell it from a logger falling behind)")
    p.add_argument("--delimiter", default=",", help="the cell separator (default: ','; e.g. ';')")
    p.add_argument("--time-unit", choices=sorted(TIME_SCALES), default="s",
                   help="unit of the time or arrival column (default: s)")
    p.add_argument("--check-time-col", metavar="COL",
                   help="with --arrival-col: a trusted sample-time column (same unit) to print the "
                        "re-timing's error against; the output does not use it")
    p.add_argument("--acc-col", required=True, help="column with the acceleration along the measured axis")
    p.add_argument("--acc-y-col", help="optional column with a second axis")
    p.add_argument("--acc-unit", choices=sorted(UNIT_SCALES), default="mps2",
                   help="unit of the acceleration columns: g, mg or mps2 (default: mps2)")
    p.add_argument("--acc-scale", type=float, default=1.0,
                   help="extra factor applied after the unit, e.g. -1 to flip the axis (default: 1)")
    p.add_argument("--temp-col", help="optional column with temperature in °C")
    p.add_argument("--ref-pos-col", help="reference position along the measured axis → ref_pos_m")
    p.add_argument("--ref-vel-col", help="reference velocity → ref_vel_mps")
    p.add_argument("--ref-acc-col", help="reference acceleration → ref_acc_mps2")
    p.add_argument("--ref-unit", choices=sorted(LENGTH_SCALES), default="m",
                   help="length unit of the reference columns: m (m, m/s, m/s²) or mm (default: m)")
    p.add_argument("--ref-scale", type=float, default=1.0,
                   help="extra factor on the reference, e.g. -1 when it counts the other way (default: 1)")
    p.add_argument("--ref-clock", choices=("sample", "arrival"), default="sample",
                   help="when each row's reference was taken: at the row's sample (default), or when the "
                        "PC received the row (--arrival-col): then it is interpolated at the recovered "
                        "sample times, empty cells between filled, none extrapolated")
    p.add_argument("--ref-delay-s", type=float, default=0.0,
                   help="the reference is this late: the value taken at time t is the motion at t − delay "
                        "(e.g. a robot controller's reporting lag); interpolated (default: 0)")
    p.add_argument("--hint-col", help=f"the machine's standstill hint → {HINT_COLUMN} (1 rest, 0 moving, "
                                      "empty unknown)")
    p.add_argument("--hint-rest-value", default="1", help="cell value meaning 'at rest' (default: 1)")
    p.add_argument("--hint-moving-value", default="0", help="cell value meaning 'moving' (default: 0)")
    p.add_argument("--out", required=True, help="output recording")
    p.set_defaults(run=run)


def _check_args(args) -> None:
    for name in ("acc_scale", "ref_scale"):
        value = getattr(args, name)
        if not math.isfinite(value) or value == 0:
            raise RecordingError(f"--{name.replace('_', '-')} {value!r} must be a finite non-zero number")
    if args.check_time_col and not args.arrival_col:
        raise RecordingError("--check-time-col needs --arrival-col (it checks the re-timed sample times)")
    if args.ref_clock == "arrival" and not args.arrival_col:
        raise RecordingError("--ref-clock arrival needs --arrival-col (the arrival times it was taken at)")
    if not math.isfinite(args.ref_delay_s):
        raise RecordingError(f"--ref-delay-s {args.ref_delay_s!r} must be a finite number of seconds")
    if args.nominal_rate_hz and not args.arrival_col:
        raise RecordingError("--nominal-rate-hz needs --arrival-col (it guides the re-timing)")
    if args.hint_rest_value == args.hint_moving_value:
        raise RecordingError("--hint-rest-value and --hint-moving-value must differ")


def _retime(args, arrival_s: np.ndarray, lines: list[int]) -> Retiming:
    try:
        return retime(arrival_s, RetimingSettings(nominal_rate_hz=args.nominal_rate_hz))
    except RetimingError as err:
        # the core counts rows from 0 among the rows kept; the user wants the file's line
        where = args.foreign if err.row is None else f"{args.foreign}:{lines[err.row]}"
        raise RecordingError(f"{where}: column {args.arrival_col!r}: {err.what}") from None


def _report_retiming(r: Retiming, lines: list[int]) -> list[str]:
    ms = 1e3
    out = [f"re-timed from arrival times: sensor clock {r.rate_hz:.4f} samples/s "
           f"(period {r.period_s * ms:.4f} ms on the arrival clock; {r.passes} fit passes)"]
    out.append(f"  arrivals: {r.bursts} bursts of ≥ 2 rows (median {r.burst_rows_median:g} rows, "
               f"{r.burst_interval_s * ms:.1f} ms apart inside, {r.between_bursts_s * ms:.1f} ms between)")
    if r.falling_behind:
        out.append("  warning: the arrivals fall behind the sensor for good at the end (with the nominal "
                   "rate given, taken as the logger falling behind)")
    for ep in r.late:
        kind = "start-up backlog" if ep.start == 0 else "late stretch"
        out.append(f"  {kind}: lines {lines[ep.start]}–{lines[ep.stop - 1]} ({ep.stop - ep.start} rows) up to "
                   f"{ep.max_delay_s:.3f} s late, arriving {ep.arrival_interval_s * ms:.1f} ms apart")
    if r.blind_rows:
        out.append(f"  a gap among the first {r.blind_rows} rows cannot be seen (no on-time arrival before them)")
    gaps = r.gaps
    lost = int(r.lost_before.sum())
    listed = ", ".join(f"line {lines[row]} ({n})" for row, n in gaps[:10]) + (" …" if len(gaps) > 10 else "")
    out.append(f"  gaps: {len(gaps)}, {lost} samples lost" + (f": before {listed}" if gaps else ""))
    out.append(f"  a gap after line {lines[r.unconfirmed_from]} (the last {len(lines) - r.unconfirmed_from} "
               "rows) cannot be confirmed")
    d = r.delay_s[r.on_time]
    out.append(f"  fit residual: the clock's line lies under every arrival; the nearest arrival per "
               f"{RetimingSettings().window_s:g} s is median {np.median(r.floor_s) * ms:.2f} ms, at most "
               f"{r.floor_s.max() * ms:.2f} ms above it (the spread is how far the times may be off: "
               f"a wandering sensor clock or delay floor); delays outside late stretches median "
               f"{np.median(d) * ms:.2f} ms, 95 % {np.percentile(d, 95) * ms:.2f} ms, max {d.max() * ms:.1f} ms")
    return out


@dataclass
class Imported:
    """What an import wrote, for its report."""

    rows: int
    last_t_s: float
    skipped_rows: int  # rows without a time or an acceleration
    notes: list[str]  # the re-timing's account, the check against a time column


def run(args: argparse.Namespace) -> int:
    """parse (the arguments, the output path) → do (the import) → report."""
    _check_args(args)
    check_output(args.out)  # before the work
    # the re-timing fits the whole file's arrivals, a delayed reference is resampled
    # across rows: both need every row at once; otherwise the file is streamed
    whole = args.arrival_col or args.ref_delay_s != 0
    imported = _run_whole(args) if whole else _run_streamed(args)
    return _wrote(args, imported)


def _check_increasing(args, t_in: np.ndarray, lines: np.ndarray, before_s: float = -math.inf) -> None:
    back = np.flatnonzero(np.diff(np.concatenate([[before_s], t_in])) <= 0)
    if back.size:
        raise RecordingError(f"{args.foreign}:{lines[back[0]]}: column {args.time_col!r}: time does not increase")


def _check_rate(args, t_in: np.ndarray) -> None:
    rate_hz = 1.0 / float(np.median(np.diff(t_in)))
    if rate_hz < MIN_RATE_HZ:
        raise RecordingError(
            f"{args.foreign}: column {args.time_col!r} read in {args.time_unit}: {rate_hz:.3g} samples/s, too slow "
            f"for an accelerometer's log (a move of the paper or the robot lasts under a second: fewer than "
            f"{MIN_RATE_HZ:g} sample/s cannot follow it); a time in another unit? give --time-unit")


def _too_few(args, rows: int, need: int) -> RecordingError:
    return RecordingError(f"{args.foreign}: {rows} rows with both {args.arrival_col or args.time_col!r} and "
                          f"{args.acc_col!r}; {'re-timing needs' if args.arrival_col else 'a recording needs'} "
                          f"at least {need}")


def _metadata(args) -> dict[str, str]:
    time_col = args.arrival_col or args.time_col
    roles = _wanted(args)
    return {"source": "import", "axis": "x", "imported_from": args.foreign.replace("\n", " "),
            "imported_columns": (
                f"time={time_col} ({args.time_unit}), acc_x={args.acc_col} ({args.acc_unit} × {args.acc_scale:g})"
                + (f", acc_y={args.acc_y_col}" if args.acc_y_col else "")
                + "".join(f", {REFERENCE_ROLES[r]}={getattr(args, r + '_col')} ({args.ref_unit} × {args.ref_scale:g})"
                          for r in REFERENCE_ROLES if r in roles)
                + (f", reference taken at the {args.ref_clock} time, {args.ref_delay_s:g} s late"
                   if any(r in roles for r in REFERENCE_ROLES) else "")
                + (f", {HINT_COLUMN}={args.hint_col}" if args.hint_col else ""))}


def _columns(args, values: dict[str, np.ndarray], t_s: np.ndarray, t_host_s: np.ndarray | None,
             resample: bool = False) -> dict[str, np.ndarray]:
    """The recording's columns for these rows (the reference resampled only when asked:
    `_run_whole`, which has every row)."""
    scale = UNIT_SCALES[args.acc_unit] * args.acc_scale
    columns = {"t_s": t_s, "acc_x_mps2": np.array(values["acc"], dtype=float) * scale}
    if "acc_y" in values:
        columns["acc_y_mps2"] = np.array(values["acc_y"], dtype=float) * scale
    if "temp" in values:
        columns["temp_c"] = np.array(values["temp"], dtype=float)
    if t_host_s is not None:
        columns["t_host_s"] = t_host_s
    ref_scale = LENGTH_SCALES[args.ref_unit] * args.ref_scale
    # the reference as a signal of time: taken at t_ref (sample or arrival time), describing
    # the motion at t_ref − delay, wanted at the sample times
    t_ref = t_host_s if args.ref_clock == "arrival" else t_s
    for role, column in REFERENCE_ROLES.items():
        if role in values:
            ref = np.array(values[role], dtype=float) * ref_scale
            columns[column] = on_sample_clock(t_ref - args.ref_delay_s, ref, t_s) if resample else ref
    if "hint" in values:
        columns[HINT_COLUMN] = np.array(values["hint"], dtype=float)
    return columns


def _wrote(args, imported: Imported) -> int:
    rows, last_t_s = imported.rows, imported.last_t_s
    rate = (rows - 1) / last_t_s
    print(f"wrote {args.out}: {rows} samples, {last_t_s:.3f} s, {rate:.1f} samples/s; "
          f"skipped {imported.skipped_rows} rows without {args.arrival_col or args.time_col!r}/{args.acc_col!r}",
          file=sys.stderr)
    for note in imported.notes:
        print(note, file=sys.stderr)
    return 0


def _run_streamed(args: argparse.Namespace) -> Imported:
    """A trusted time column: block by block from the file to the recording, so memory
    follows the block (BLOCK_ROWS rows), not the file. The rate is judged on the first
    block (a time column in the wrong unit is wrong on every row alike)."""
    skipped = _Skipped()
    rows, last_t_s, writer = 0, -math.inf, None
    try:
        for values, lines in foreign_blocks(args, skipped):
            t_in = values["time"] * TIME_SCALES[args.time_unit]  # seconds since the first row
            _check_increasing(args, t_in, lines, last_t_s)
            if writer is None:
                if t_in.size < 2:
                    rows = t_in.size
                    break  # a file of one row: too few, said below
                _check_rate(args, t_in)
            columns = _columns(args, values, t_in, None)
            if writer is None:
                writer = ColumnWriter(args.out, list(columns), {"format": FORMAT_ID, **_metadata(args)})
            writer.write(columns)
            rows += t_in.size
            last_t_s = float(t_in[-1])
        if rows < 2:
            raise _too_few(args, rows, 2)
        writer.commit()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    return Imported(rows, last_t_s, skipped.rows, [])


def _run_whole(args: argparse.Namespace) -> Imported:
    values, lines, skipped = read_foreign(args)
    time_col = args.arrival_col or args.time_col
    need = RetimingSettings().min_rows if args.arrival_col else 2
    if len(lines) < need:
        raise _too_few(args, len(lines), need)
    t_in = values["time"] * TIME_SCALES[args.time_unit]  # seconds since the first row
    if not args.arrival_col:  # arrival times are checked by the re-timing
        _check_increasing(args, t_in, lines)
        _check_rate(args, t_in)

    notes: list[str] = []
    metadata = _metadata(args)
    if args.arrival_col:
        timing = _retime(args, t_in, lines)
        tail = timing.falling_behind
        if tail and not args.nominal_rate_hz:
            raise RecordingError(
                f"{args.foreign}: column {time_col!r}: cannot tell the sensor's rate: lines {lines[tail.start]}–"
                f"{lines[-1]} arrive {tail.arrival_interval_s * 1e3:.1f} ms apart and later and later to the end, "
                f"after rows {timing.period_s * 1e3:.1f} ms apart; either the logger fell behind a "
                f"{timing.rate_hz:.0f} Hz sensor or the rows before were a start-up backlog flushed faster "
                f"than a ~{1 / tail.arrival_interval_s:.0f} Hz sensor: give --nominal-rate-hz")
        origin = timing.t_s[0]
        t_s = timing.t_s - origin
        t_host_s = t_in - origin
        notes += _report_retiming(timing, lines)
        metadata.update({
            "retimed_from": f"{time_col} ({args.time_unit})",
            "retimed_rate_hz": f"{timing.rate_hz:.6f}",
            "retimed_lost_samples": str(int(timing.lost_before.sum())),
            "retimed_gaps": str(len(timing.gaps)),
            "retimed_blind_rows": str(timing.blind_rows),
            "retimed_floor_max_ms": f"{timing.floor_s.max() * 1e3:.3f}",
        })
        if args.check_time_col:
            empty = np.flatnonzero(np.isnan(values["check"]))
            if empty.size:
                raise RecordingError(f"{args.foreign}:{lines[empty[0]]}: column {args.check_time_col!r}: empty cell "
                                     "(the check needs a time in every row)")
            err = timing_error(t_s, values["check"] * TIME_SCALES[args.time_unit])
            notes.append(f"  against {args.check_time_col!r}: timing error max {err.max_s * 1e3:.2f} ms, "
                         f"RMS {err.rms_s * 1e3:.2f} ms, sample-spacing RMS {err.interval_rms_s * 1e3:.3f} ms "
                         f"(after removing a constant {err.offset_s:.4f} s)")
    else:
        t_s, t_host_s = t_in, None
    resample = args.ref_clock == "arrival" or args.ref_delay_s != 0
    write_recording(args.out, metadata, _columns(args, values, t_s, t_host_s, resample))
    return Imported(t_s.size, float(t_s[-1]), skipped, notes)
