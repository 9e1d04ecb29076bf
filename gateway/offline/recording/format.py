"""The recording format (shared/spec/recording-format.md): its columns, its two forms, a
recording in memory, and how a CSV file's head (metadata lines, header) and any chunk of
rows are checked — whatever file the rows came from."""
from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gateway.core.conversion import AxisCalibration, Calibration
from gateway.errors import RecordingError

FORMAT_ID = "adxl-recording/1"
RAW_REQUIRED = ("seq", "t1x", "t1y", "t2")
ACC_REQUIRED = ("t_s", "acc_x_mps2")
REFERENCE_COLUMNS = ("ref_pos_m", "ref_vel_mps", "ref_acc_mps2")
# the machine's word on the axis (PLC / robot controller "in position"): 1 at rest, 0 moving,
# empty unknown; `adxlgw estimate` uses it unless --ignore-hint
HINT_COLUMN = "standstill_hint"
INTEGER_COLUMNS = ("seq", "t1x", "t1y", "t2", "flags")
PARQUET_SUFFIXES = (".parquet", ".pq")

MAX_LINE_BYTES = 65_536
MAX_HEAD_BYTES = 1 << 20



def is_parquet(path: str | os.PathLike) -> bool:
    return str(path).lower().endswith(PARQUET_SUFFIXES)



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
        return calibration_from(self.path, self.metadata)


def calibration_from(path: str, metadata: dict[str, str]) -> Calibration:
    """Per-axis calibration from metadata (cal_d0_x, cal_s_x, …), nominal where absent."""
    axes = {}
    for axis in ("x", "y"):
        try:
            axes[axis] = AxisCalibration(
                float(metadata.get(f"cal_d0_{axis}", 0.5)),
                float(metadata.get(f"cal_s_{axis}", 0.125)),
            )
        except ValueError as err:
            raise RecordingError(f"{path}: metadata cal_*_{axis}: {err}") from err
    return Calibration(**axes)



def located_error(path, line, column, what) -> RecordingError:
    where = f"{path}:{line}" + (f": column {column!r}" if column else "")
    return RecordingError(f"{where}: {what}")


def cell_text(cell: str) -> str:
    return repr(cell if len(cell) <= 40 else cell[:40] + "…")


# ---- the head of a CSV file: metadata lines and the header --------------------------------


@dataclass
class CsvHead:
    metadata: dict[str, str]
    header: list[str]
    header_line: int  # 1-based line number of the header row
    data_offset: int  # byte offset of the first data line


def decoded(raw: bytes, path: str, offset: int, line: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise located_error(path, line, None,
                            f"not UTF-8 text ({err.reason}) at byte offset {offset + err.start}") from None


def parse_head(head: bytes, path: str, at_eof: bool) -> CsvHead:
    metadata: dict[str, str] = {}
    offset = 0
    line_no = 0
    while True:
        end = head.find(b"\n", offset)
        if end < 0:
            if not at_eof or len(head) - offset > MAX_LINE_BYTES:
                raise located_error(path, line_no + 1, None,
                             f"metadata and header longer than {MAX_HEAD_BYTES} bytes, or a line longer than "
                             f"{MAX_LINE_BYTES} bytes")
            end = len(head)
        line_no += 1
        if end - offset > MAX_LINE_BYTES:
            raise located_error(path, line_no, None, f"line longer than {MAX_LINE_BYTES} bytes")
        text = decoded(head[offset:end], path, offset, line_no).rstrip("\r")
        next_offset = min(end + 1, len(head))
        if text.startswith("#") or not text.strip():
            body = text[1:].strip()
            if "=" in body:
                key, value = body.split("=", 1)
                metadata[key.strip()] = value.strip()
            if next_offset >= len(head) and at_eof:
                raise located_error(path, line_no, None, "no header row (the file has only metadata or is empty)")
            offset = next_offset
            continue
        header = [h.strip() for h in next(csv.reader([text]))]
        return CsvHead(metadata, header, line_no, next_offset)


def form_of(path: str, header: list[str], metadata: dict[str, str], header_line) -> str:
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise located_error(path, header_line, dup[0], "column appears more than once in the header")
    if all(c in header for c in RAW_REQUIRED):
        if "tick_hz" not in metadata:
            raise located_error(path, 1, None, "raw form (seq, t1x, t1y, t2) needs the metadata line '# tick_hz=…'")
        try:
            tick_hz = float(metadata["tick_hz"])
        except ValueError:
            tick_hz = float("nan")
        if not (math.isfinite(tick_hz) and tick_hz > 0):
            raise located_error(path, 1, None, f"metadata tick_hz={metadata['tick_hz']!r} is not a positive number")
        return "raw"
    if all(c in header for c in ACC_REQUIRED):
        return "acceleration"
    missing_raw = [c for c in RAW_REQUIRED if c not in header]
    missing_acc = [c for c in ACC_REQUIRED if c not in header]
    raise located_error(
        path, header_line, None,
        f"neither recording form: raw form lacks column(s) {', '.join(missing_raw)}; "
        f"acceleration form lacks {', '.join(missing_acc)}",
    )


# ---- validation of a chunk, whatever file it came from ------------------------------------


class ChunkValidator:
    """The spec's rules on values, chunk by chunk (sample times must increase across chunks)."""

    def __init__(self, path: str, form: str):
        self.path = path
        self.form = form
        self._last_t: float | None = None

    def check(self, cols: dict[str, np.ndarray], where: Callable[[int], str]) -> None:
        """where(i): 'path:line' (CSV) or 'path: row n' (Parquet) of the chunk's i-th row."""
        if HINT_COLUMN in cols:
            hint = cols[HINT_COLUMN]
            bad = np.flatnonzero(np.isfinite(hint) & (hint != 0.0) & (hint != 1.0))
            if bad.size:
                raise RecordingError(f"{where(int(bad[0]))}: column {HINT_COLUMN!r}: {float(hint[bad[0]])!r} is not "
                                     "1 (at rest), 0 (moving) or empty (unknown)")
        if self.form == "raw":
            for name in RAW_REQUIRED:
                bad = np.flatnonzero(~np.isfinite(cols[name]))
                if bad.size:
                    raise RecordingError(f"{where(int(bad[0]))}: column {name!r}: required cell is empty or not finite")
            for name in INTEGER_COLUMNS:
                if name in cols:
                    col = cols[name]
                    bad = np.flatnonzero(np.isfinite(col) & ((col != np.round(col)) | (col < 0) | (col > 65535)))
                    if bad.size:
                        raise RecordingError(f"{where(int(bad[0]))}: column {name!r}: "
                                             f"{float(col[bad[0]])!r} is not an integer count 0–65535")
            return
        t = cols["t_s"]
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise RecordingError(f"{where(int(bad[0]))}: column 't_s': sample time is empty or not finite")
        if t.size:
            if self._last_t is not None and not t[0] > self._last_t:
                raise RecordingError(f"{where(0)}: column 't_s': sample times must increase")
            back = np.flatnonzero(np.diff(t) <= 0)
            if back.size:
                raise RecordingError(f"{where(int(back[0]) + 1)}: column 't_s': sample times must increase")
            self._last_t = float(t[-1])

