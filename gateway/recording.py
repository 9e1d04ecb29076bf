"""Recording files (shared/spec/recording-format.md): read, validate, write.

Reading turns either form into an ``AccelerationSeries`` for the offline commands.
Every problem is a ``RecordingError`` whose message names the file, line and column.
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.core.conversion import (
    Calibration,
    AxisCalibration,
    acceleration_mps2,
    axis_valid,
    lost_before_from_seq,
    sample_times_s,
)
from gateway.errors import RecordingError

FORMAT_ID = "adxl-recording/1"
RAW_REQUIRED = ("seq", "t1x", "t1y", "t2")
ACC_REQUIRED = ("t_s", "acc_x_mps2")
REFERENCE_COLUMNS = ("ref_pos_m", "ref_vel_mps", "ref_acc_mps2")
# the machine's word on the axis (PLC / robot controller "in position"): 1 at rest, 0 moving,
# empty unknown; `adxlgw estimate` uses it unless --ignore-hint
HINT_COLUMN = "standstill_hint"
INTEGER_COLUMNS = ("seq", "t1x", "t1y", "t2", "flags")
HINT_COLUMN = "standstill_hint"  # the machine's word on the axis: 1 at rest, 0 moving, empty unknown


@dataclass
class Recording:
    path: str
    metadata: dict[str, str]
    columns: dict[str, np.ndarray]
    form: str  # "raw" or "acceleration"

    def __len__(self) -> int:
        return next(iter(self.columns.values())).size if self.columns else 0

    def has(self, name: str) -> bool:
        return name in self.columns and not np.all(np.isnan(self.columns[name]))

    @property
    def tick_hz(self) -> float:
        return float(self.metadata["tick_hz"])

    def calibration(self) -> Calibration:
        """Per-axis calibration from metadata (cal_d0_x, cal_s_x, …), nominal where absent."""
        axes = {}
        for axis in ("x", "y"):
            try:
                axes[axis] = AxisCalibration(
                    float(self.metadata.get(f"cal_d0_{axis}", 0.5)),
                    float(self.metadata.get(f"cal_s_{axis}", 0.125)),
                )
            except ValueError as err:
                raise RecordingError(f"{self.path}: metadata cal_*_{axis}: {err}") from err
        return Calibration(**axes)


@dataclass
class AccelerationSeries:
    """What the estimators read: sample times and acceleration along the measured axis."""

    t_s: np.ndarray
    acc_mps2: np.ndarray  # along the axis the reference refers to; NaN where invalid
    valid: np.ndarray
    lost_before: np.ndarray
    other_axis_mps2: np.ndarray | None = None
    reference: dict[str, np.ndarray] = field(default_factory=dict)
    temp_c: np.ndarray | None = None
    t_host_s: np.ndarray | None = None
    axis: str = "x"
    standstill_hint: np.ndarray | None = None  # 1 at rest, 0 moving, NaN unknown


    def __len__(self) -> int:
        return self.t_s.size


def _error(path, line, column, what) -> RecordingError:
    where = f"{path}:{line}" + (f": column {column!r}" if column else "")
    return RecordingError(f"{where}: {what}")


def read_recording(path: str | os.PathLike) -> Recording:
    path = str(path)
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            text = fh.read()
    except OSError as err:
        raise RecordingError(f"{path}: cannot read: {err.strerror or err}") from err
    except UnicodeDecodeError as err:
        raise RecordingError(f"{path}: not a UTF-8 text file ({err.reason} at byte {err.start})") from err
    return parse_recording(text, path)


def parse_recording(text: str, path: str = "<recording>") -> Recording:
    lines = text.splitlines()
    metadata: dict[str, str] = {}
    line_no = 0
    while line_no < len(lines) and (lines[line_no].startswith("#") or not lines[line_no].strip()):
        body = lines[line_no][1:].strip()
        if "=" in body:
            key, value = body.split("=", 1)
            metadata[key.strip()] = value.strip()
        line_no += 1
    if line_no >= len(lines):
        raise _error(path, line_no, None, "no header row (the file has only metadata or is empty)")
    header_line = line_no + 1
    header = [h.strip() for h in next(csv.reader([lines[line_no]]))]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise _error(path, header_line, dup[0], "column appears more than once in the header")
    if all(c in header for c in RAW_REQUIRED):
        form = "raw"
        if "tick_hz" not in metadata:
            raise _error(path, 1, None, "raw form (seq, t1x, t1y, t2) needs the metadata line '# tick_hz=…'")
        try:
            tick_hz = float(metadata["tick_hz"])
        except ValueError:
            tick_hz = float("nan")
        if not (math.isfinite(tick_hz) and tick_hz > 0):
            raise _error(path, 1, None, f"metadata tick_hz={metadata['tick_hz']!r} is not a positive number")
    elif all(c in header for c in ACC_REQUIRED):
        form = "acceleration"
    else:
        missing_raw = [c for c in RAW_REQUIRED if c not in header]
        missing_acc = [c for c in ACC_REQUIRED if c not in header]
        raise _error(
            path, header_line, None,
            f"neither recording form: raw form lacks column(s) {', '.join(missing_raw)}; "
            f"acceleration form lacks {', '.join(missing_acc)}",
        )

    rows = list(csv.reader(lines[line_no + 1:]))
    width = len(header)
    data = np.full((len(rows), width), np.nan)
    n = 0
    for i, row in enumerate(rows):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue  # blank line
        if len(row) != width:
            raise _error(path, header_line + 1 + i, None, f"has {len(row)} cells, the header has {width}")
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell:
                try:
                    data[n, j] = float(cell)
                except ValueError:
                    raise _error(path, header_line + 1 + i, header[j], f"{cell!r} is not a number") from None
        n += 1
    data = data[:n]
    if n == 0:
        raise _error(path, header_line, None, "no data rows")
    columns = {name: data[:, j].copy() for j, name in enumerate(header)}
    if HINT_COLUMN in columns:
        hint = columns[HINT_COLUMN]
        bad = np.flatnonzero(np.isfinite(hint) & (hint != 0) & (hint != 1))
        if bad.size:
            raise _error(path, header_line + 1 + int(bad[0]), HINT_COLUMN,
                         f"{float(hint[bad[0]])!r} is not 1 (at rest), 0 (moving) or empty (unknown)")
    required = RAW_REQUIRED if form == "raw" else ACC_REQUIRED
    for name in required:
        bad = np.flatnonzero(~np.isfinite(columns[name]))
        if form == "raw" and bad.size:
            raise _error(path, header_line + 1 + int(bad[0]), name, "required cell is empty or not finite")
    if form == "raw":
        for name in INTEGER_COLUMNS:
            if name in columns:
                col = columns[name]
                bad = np.flatnonzero(np.isfinite(col) & ((col != np.round(col)) | (col < 0) | (col > 65535)))
                if bad.size:
                    raise _error(path, header_line + 1 + int(bad[0]), name,
                                 f"{float(col[bad[0]])!r} is not an integer count 0–65535")
    else:
        t = columns["t_s"]
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise _error(path, header_line + 1 + int(bad[0]), "t_s", "sample time is empty or not finite")
        back = np.flatnonzero(np.diff(t) <= 0)
        if back.size:
            raise _error(path, header_line + 2 + int(back[0]), "t_s", "sample times must increase")
    if HINT_COLUMN in columns:
        hint = columns[HINT_COLUMN]
        bad = np.flatnonzero(np.isfinite(hint) & (hint != 0.0) & (hint != 1.0))
        if bad.size:
            raise _error(path, header_line + 1 + int(bad[0]), HINT_COLUMN,
                         f"{float(hint[bad[0]])!r} is not 1 (at rest), 0 (moving) or empty (unknown)")
    return Recording(path, metadata, columns, form)


def to_acceleration(rec: Recording, calibration: Calibration | None = None) -> AccelerationSeries:
    """Either form → sample time and acceleration along the measured axis."""
    axis = rec.metadata.get("axis", "x").strip().lower()
    if axis not in ("x", "y"):
        raise RecordingError(f"{rec.path}: metadata axis={axis!r} must be 'x' or 'y'")
    c = rec.columns
    if rec.form == "raw":
        cal = calibration or rec.calibration()
        flags = np.nan_to_num(c["flags"], nan=0.0).astype(np.int64) if "flags" in c else np.zeros(len(rec), np.int64)
        lost = lost_before_from_seq(c["seq"])
        try:
            t_s = sample_times_s(c["t2"], rec.tick_hz, lost)
        except ValueError as err:
            raise RecordingError(f"{rec.path}: {err}") from err
        acc = {}
        valid = {}
        for ax in ("x", "y"):
            t1 = c[f"t1{ax}"]
            valid[ax] = axis_valid(flags, t1, c["t2"], ax)
            acc[ax] = np.where(valid[ax], acceleration_mps2(t1, c["t2"], getattr(cal, ax)), np.nan)
        main, other = (("x", "y") if axis == "x" else ("y", "x"))
        acc_main, acc_other, valid_main = acc[main], acc[other], valid[main]
    else:
        t_s = c["t_s"]
        lost = np.zeros(t_s.size, dtype=np.int64)
        acc_main = c["acc_x_mps2"] if axis == "x" or "acc_y_mps2" not in c else c["acc_y_mps2"]
        acc_other = c.get("acc_y_mps2") if axis == "x" else c.get("acc_x_mps2")
        valid_main = np.isfinite(acc_main)
    reference = {k: c[k] for k in REFERENCE_COLUMNS if k in c and rec.has(k)}
    return AccelerationSeries(
        t_s=t_s,
        acc_mps2=np.where(valid_main, acc_main, np.nan),
        valid=valid_main & np.isfinite(acc_main),
        lost_before=lost,
        other_axis_mps2=acc_other,
        reference=reference,
        temp_c=c.get("temp_c"),
        t_host_s=c.get("t_host_s"),
        axis=axis,
        standstill_hint=c.get(HINT_COLUMN),
    )


def _format_column(name: str, col: np.ndarray) -> list[str]:
    if name in INTEGER_COLUMNS or col.dtype.kind in "iu":
        return ["" if not np.isfinite(v) else str(int(v)) for v in col.astype(float)]
    return ["" if not np.isfinite(v) else repr(float(v)) for v in col]


def format_recording(metadata: dict[str, str], columns: dict[str, np.ndarray]) -> str:
    out = io.StringIO()
    meta = {"format": FORMAT_ID, **metadata}
    for key, value in meta.items():
        out.write(f"# {key}={value}\n")
    names = list(columns)
    out.write(",".join(names) + "\n")
    cells = [_format_column(n, np.asarray(columns[n])) for n in names]
    for row in zip(*cells):
        out.write(",".join(row) + "\n")
    return out.getvalue()


def write_recording(path: str | os.PathLike, metadata: dict[str, str], columns: dict[str, np.ndarray]) -> None:
    """Write atomically: a reader never sees half a file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(format_recording(metadata, columns))
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise RecordingError(f"{path}: cannot write: {err.strerror or err}") from err


class RecordingWriter:
    """Streams rows to a file as they arrive (for `adxlgw record`)."""

    def __init__(self, path: str | os.PathLike, metadata: dict[str, str], names: list[str]):
        self.path = str(path)
        self.names = names
        try:
            self._fh = open(path, "w", encoding="utf-8", newline="")
        except OSError as err:
            raise RecordingError(f"{path}: cannot write: {err.strerror or err}") from err
        for key, value in {"format": FORMAT_ID, **metadata}.items():
            self._fh.write(f"# {key}={value}\n")
        self._fh.write(",".join(names) + "\n")
        self.rows = 0

    def write_row(self, values: dict[str, object]) -> None:
        cells = []
        for n in self.names:
            v = values.get(n)
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                cells.append("")
            elif isinstance(v, float):
                cells.append(repr(v))
            else:
                cells.append(str(v))
        self._fh.write(",".join(cells) + "\n")
        self.rows += 1

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
