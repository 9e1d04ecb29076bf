"""adxlgw import: another logger's CSV → a recording in the acceleration form."""
from __future__ import annotations

import argparse
import csv
import math
import sys
from decimal import Decimal, InvalidOperation

import numpy as np

from gateway.commands.common import positive_float
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.errors import RecordingError
from gateway.recording import write_recording

UNIT_SCALES = {"g": STANDARD_GRAVITY_MPS2, "mps2": 1.0, "mg": STANDARD_GRAVITY_MPS2 / 1000}
TIME_SCALES = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "import",
        help="convert another logger's CSV into a recording (acceleration form)",
        description="Read a foreign CSV, take one time column and one or two acceleration columns, "
                    "scale them to seconds and m/s², and write a recording in the acceleration form. "
                    "Rows whose time or acceleration cell is empty are skipped and counted "
                    "(e.g. interleaved rows of another kind).",
    )
    p.add_argument("foreign", metavar="FOREIGN.csv")
    p.add_argument("--time-col", required=True, help="column with the sample time")
    p.add_argument("--time-unit", choices=sorted(TIME_SCALES), default="s", help="unit of the time column (default: s)")
    p.add_argument("--acc-col", required=True, help="column with the acceleration along the measured axis")
    p.add_argument("--acc-y-col", help="optional column with a second axis")
    p.add_argument("--acc-unit", choices=sorted(UNIT_SCALES), default="mps2",
                   help="unit of the acceleration columns: g, mg or mps2 (default: mps2)")
    p.add_argument("--acc-scale", type=float, default=1.0,
                   help="extra factor applied after the unit, e.g. -1 to flip the axis (default: 1)")
    p.add_argument("--temp-col", help="optional column with temperature in °C")
    p.add_argument("--out", required=True, help="output recording")
    p.set_defaults(run=run)


def _number(cell: str, path: str, line: int, column: str):
    """Integers stay exact (nanosecond timestamps exceed float precision); others are floats."""
    try:
        return int(cell)
    except ValueError:
        pass
    try:
        value = float(cell)
    except ValueError:
        raise RecordingError(f"{path}:{line}: column {column!r}: {cell!r} is not a number") from None
    if not math.isfinite(value):
        raise RecordingError(f"{path}:{line}: column {column!r}: {cell!r} is not finite")
    return value


def run(args: argparse.Namespace) -> int:
    if not math.isfinite(args.acc_scale) or args.acc_scale == 0:
        raise RecordingError(f"--acc-scale {args.acc_scale!r} must be a finite non-zero number")
    try:
        fh = open(args.foreign, encoding="utf-8", newline="")
    except OSError as err:
        raise RecordingError(f"{args.foreign}: cannot read: {err.strerror or err}") from err
    with fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise RecordingError(f"{args.foreign}:1: empty file, no header row") from None
        wanted = {"time": args.time_col, "acc": args.acc_col}
        if args.acc_y_col:
            wanted["acc_y"] = args.acc_y_col
        if args.temp_col:
            wanted["temp"] = args.temp_col
        index = {}
        for role, name in wanted.items():
            if name not in header:
                raise RecordingError(f"{args.foreign}:1: no column {name!r} in the header")
            index[role] = header.index(name)
        values = {role: [] for role in wanted}
        skipped = 0
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            cells = {role: (row[i].strip() if i < len(row) else "") for role, i in index.items()}
            if not cells["time"] or not cells["acc"]:
                skipped += 1
                continue
            for role, cell in cells.items():
                values[role].append(_number(cell, args.foreign, line, wanted[role]) if cell else float("nan"))
    if len(values["time"]) < 2:
        raise RecordingError(f"{args.foreign}: fewer than two rows with both {args.time_col!r} and {args.acc_col!r}")
    t0 = values["time"][0]
    t_s = np.array([float(Decimal(t - t0) if isinstance(t, int) and isinstance(t0, int) else (t - t0))
                    for t in values["time"]]) * TIME_SCALES[args.time_unit]
    back = np.flatnonzero(np.diff(t_s) <= 0)
    if back.size:
        raise RecordingError(f"{args.foreign}: column {args.time_col!r}: time does not increase at data row {back[0] + 2}")
    scale = UNIT_SCALES[args.acc_unit] * args.acc_scale
    columns = {"t_s": t_s, "acc_x_mps2": np.array(values["acc"], dtype=float) * scale}
    if "acc_y" in values:
        columns["acc_y_mps2"] = np.array(values["acc_y"], dtype=float) * scale
    if "temp" in values:
        columns["temp_c"] = np.array(values["temp"], dtype=float)
    metadata = {
        "source": "import",
        "axis": "x",
        "imported_from": args.foreign.replace("\n", " "),
        "imported_columns": f"time={args.time_col} ({args.time_unit}), acc_x={args.acc_col} ({args.acc_unit} × {args.acc_scale:g})"
        + (f", acc_y={args.acc_y_col}" if args.acc_y_col else ""),
    }
    write_recording(args.out, metadata, columns)
    rate = (t_s.size - 1) / t_s[-1]
    print(f"wrote {args.out}: {t_s.size} samples, {t_s[-1]:.3f} s, {rate:.1f} samples/s; "
          f"skipped {skipped} rows without {args.time_col!r}/{args.acc_col!r}", file=sys.stderr)
    return 0
