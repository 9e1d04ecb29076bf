"""Recording files (shared/spec/recording-format.md): read, validate, write — CSV or Parquet.

Two file formats, one content: CSV as the spec describes it (``# key=value`` lines, a
header, one row per sample) and Parquet with the same columns and the metadata as the
file's key-value metadata. The format is chosen by the extension (``.parquet``/``.pq``
is Parquet, anything else CSV).

Both are read as a stream of chunks (`open_recording(...).chunks()`), parsed by pyarrow,
so memory follows the chunk, not the file; `read_recording` joins the chunks for the
commands that need every sample at once. Every problem is a ``RecordingError`` whose one
line names the file, the line (CSV) or row (Parquet), and the column.

Limits (stated in docs/board-link.md, enforced here):
- a CSV line is at most MAX_LINE_BYTES bytes (a recording's row is ~100); the metadata
  and header together at most MAX_HEAD_BYTES;
- CSV text is UTF-8; anything else is named with its byte offset;
- a whole-file read refuses a recording whose columns would not fit in the memory the
  machine has available (`whole_file_bytes`), instead of being killed.
"""
from __future__ import annotations

import csv
import io
import math
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gateway.core.chunked_conversion import RawChunkConverter, SequenceReport
from gateway.core.conversion import AxisCalibration, Calibration
from gateway.core.sensor_model import SensorParams
from gateway.errors import InputError, RecordingError

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
# bytes handed to the CSV parser at a time (~65 000 rows), rows per Parquet batch: large
# enough that the per-chunk Python work is noise, small enough that a streamed estimate
# peaks under 400 MB (measured: 16 MB blocks and 2^19-row batches peaked at ~570 MB,
# and were no faster)
BLOCK_BYTES = 4 << 20
PARQUET_BATCH_ROWS = 1 << 17
# the acceleration form's plausibility limit when the file does not state its sensor's
# range (metadata acc_range_mps2): beyond ~100 g no accelerometer this format is meant
# for (robot arms, vehicles) reads; a 1e300 sample is not a measurement
DEFAULT_ACC_RANGE_MPS2 = 1000.0


def is_parquet(path: str | os.PathLike) -> bool:
    return str(path).lower().endswith(PARQUET_SUFFIXES)


#: what a recording can be written as, by the file's extension
OUTPUT_SUFFIXES = (".csv",) + PARQUET_SUFFIXES


def check_output(path: str | os.PathLike) -> None:
    """InputError (exit 2) unless a recording can be written at `path`: an extension this
    format has (a `.xlsx` used to get CSV silently) and a directory that exists — said
    before any work, not after it."""
    text = str(path)
    if not text.lower().endswith(OUTPUT_SUFFIXES):
        raise InputError(f"--out {text}: not a recording's extension: {', '.join(OUTPUT_SUFFIXES)}")
    parent = Path(text).parent
    if not parent.is_dir():
        raise InputError(f"--out {text}: no directory {parent}")


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


@dataclass
class InputReport:
    """What reading found wrong but could carry on past: said to the user, never hidden."""

    sequence: SequenceReport = field(default_factory=SequenceReport)
    impossible: int = 0  # samples beyond the sensor's possible range: flagged invalid
    impossible_limit_mps2: float = math.inf

    def warnings(self) -> list[str]:
        out = self.sequence.problems()
        if self.impossible:
            out.append(f"{self.impossible} samples beyond ±{self.impossible_limit_mps2:.4g} m/s² (physically "
                       "impossible for the sensor): flagged invalid, not integrated")
        return out


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
    report: InputReport = field(default_factory=InputReport)
    standstill_hint: np.ndarray | None = None  # 1 at rest, 0 moving, NaN unknown

    def __len__(self) -> int:
        return self.t_s.size

    def from_time(self, t0_s: float, ref_origin_m: float = 0.0) -> AccelerationSeries:
        """The rows at or after t0_s (e.g. a sensor's settling at power-up left out), the
        reference position measured from ref_origin_m (where the estimate begins)."""
        keep = self.t_s >= t0_s
        reference = {k: v[keep] for k, v in self.reference.items()}
        if "ref_pos_m" in reference:
            reference["ref_pos_m"] = reference["ref_pos_m"] - ref_origin_m

        def cut(x):
            return None if x is None else x[keep]

        return AccelerationSeries(self.t_s[keep], self.acc_mps2[keep], self.valid[keep], self.lost_before[keep],
                                  cut(self.other_axis_mps2), reference, cut(self.temp_c), cut(self.t_host_s),
                                  self.axis, self.report, cut(self.standstill_hint))


def _error(path, line, column, what) -> RecordingError:
    where = f"{path}:{line}" + (f": column {column!r}" if column else "")
    return RecordingError(f"{where}: {what}")


def cell_text(cell: str) -> str:
    return repr(cell if len(cell) <= 40 else cell[:40] + "…")


# ---- the head of a CSV file: metadata lines and the header --------------------------------


@dataclass
class _Head:
    metadata: dict[str, str]
    header: list[str]
    header_line: int  # 1-based line number of the header row
    data_offset: int  # byte offset of the first data line


def _decode(raw: bytes, path: str, offset: int, line: int) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise _error(path, line, None, f"not UTF-8 text ({err.reason}) at byte offset {offset + err.start}") from None


def _parse_head(head: bytes, path: str, at_eof: bool) -> _Head:
    metadata: dict[str, str] = {}
    offset = 0
    line_no = 0
    while True:
        end = head.find(b"\n", offset)
        if end < 0:
            if not at_eof or len(head) - offset > MAX_LINE_BYTES:
                raise _error(path, line_no + 1, None,
                             f"metadata and header longer than {MAX_HEAD_BYTES} bytes, or a line longer than "
                             f"{MAX_LINE_BYTES} bytes")
            end = len(head)
        line_no += 1
        if end - offset > MAX_LINE_BYTES:
            raise _error(path, line_no, None, f"line longer than {MAX_LINE_BYTES} bytes")
        text = _decode(head[offset:end], path, offset, line_no).rstrip("\r")
        next_offset = min(end + 1, len(head))
        if text.startswith("#") or not text.strip():
            body = text[1:].strip()
            if "=" in body:
                key, value = body.split("=", 1)
                metadata[key.strip()] = value.strip()
            if next_offset >= len(head) and at_eof:
                raise _error(path, line_no, None, "no header row (the file has only metadata or is empty)")
            offset = next_offset
            continue
        header = [h.strip() for h in next(csv.reader([text]))]
        return _Head(metadata, header, line_no, next_offset)


def _form_of(path: str, header: list[str], metadata: dict[str, str], header_line) -> str:
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise _error(path, header_line, dup[0], "column appears more than once in the header")
    if all(c in header for c in RAW_REQUIRED):
        if "tick_hz" not in metadata:
            raise _error(path, 1, None, "raw form (seq, t1x, t1y, t2) needs the metadata line '# tick_hz=…'")
        try:
            tick_hz = float(metadata["tick_hz"])
        except ValueError:
            tick_hz = float("nan")
        if not (math.isfinite(tick_hz) and tick_hz > 0):
            raise _error(path, 1, None, f"metadata tick_hz={metadata['tick_hz']!r} is not a positive number")
        return "raw"
    if all(c in header for c in ACC_REQUIRED):
        return "acceleration"
    missing_raw = [c for c in RAW_REQUIRED if c not in header]
    missing_acc = [c for c in ACC_REQUIRED if c not in header]
    raise _error(
        path, header_line, None,
        f"neither recording form: raw form lacks column(s) {', '.join(missing_raw)}; "
        f"acceleration form lacks {', '.join(missing_acc)}",
    )


# ---- validation of a chunk, whatever file it came from ------------------------------------


class _Validator:
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


# ---- CSV text in blocks of whole lines ---------------------------------------------------


def line_blocks(file: str, name: str, offset: int = 0, first_line: int = 1):
    """The file from byte `offset` (line `first_line`) as (bytes of whole lines, 1-based line
    number of its first line, byte offset of its first byte), about BLOCK_BYTES at a time, the
    tail without a final newline last. Memory follows the block, not the file. A line longer
    than MAX_LINE_BYTES is a RecordingError naming `name` and the line. Also used by
    `adxlgw import` for foreign CSV files."""
    try:
        fh = open(file, "rb")  # noqa: SIM115 - closed by `with fh` below; only open()'s error is "cannot read"
    except OSError as err:
        raise RecordingError(f"{name}: cannot read: {err.strerror or err}") from err
    with fh:
        fh.seek(offset)
        line = first_line
        rest = b""
        while True:
            try:
                data = fh.read(BLOCK_BYTES)
            except OSError as err:
                raise RecordingError(f"{name}: cannot read: {err.strerror or err}") from err
            buf = rest + data if rest else data
            if not data:
                if buf:
                    _check_line_lengths(buf, name, line)
                    yield buf, line, offset
                return
            cut = buf.rfind(b"\n")
            if cut < 0:
                if len(buf) > MAX_LINE_BYTES:
                    raise _error(name, line, None, f"line longer than {MAX_LINE_BYTES} bytes")
                rest = buf
                continue
            block, rest = buf[:cut + 1], buf[cut + 1:]
            _check_line_lengths(block, name, line)
            yield block, line, offset
            line += block.count(b"\n")
            offset += len(block)


def _check_line_lengths(block: bytes, name: str, first_line: int) -> None:
    """Cheaply: only a block longer than the limit can hold a line longer than it."""
    if len(block) > MAX_LINE_BYTES:
        ends = np.flatnonzero(np.frombuffer(block, dtype=np.uint8) == 10)
        if not block.endswith(b"\n"):
            ends = np.append(ends, len(block))
        lengths = np.diff(np.concatenate([[-1], ends])) - 1
        if lengths.size and lengths.max() > MAX_LINE_BYTES:
            k = int(np.argmax(lengths > MAX_LINE_BYTES))
            raise _error(name, first_line + k, None,
                         f"line of {int(lengths[k])} bytes: longer than {MAX_LINE_BYTES} bytes")


# ---- sources ---------------------------------------------------------------------------


class RecordingSource:
    """An open recording: metadata and form known, rows read on demand in chunks."""

    path: str
    metadata: dict[str, str]
    names: list[str]
    form: str
    size_bytes: int

    def chunks(self, columns: list[str] | None = None, progress=None) -> Iterator[dict[str, np.ndarray]]:
        """Validated chunks, each a dict name → float64 array (NaN where empty).
        progress: an object with update(n) (a tqdm bar), advanced by `progress_total`'s unit."""
        raise NotImplementedError

    @property
    def progress_total(self) -> tuple[int, str]:
        """(total, unit) the chunks' progress counts in."""
        raise NotImplementedError

    def estimated_rows(self) -> int:
        raise NotImplementedError

    def whole_file_bytes(self, columns: list[str] | None = None) -> int:
        """Memory a whole-file read of these columns needs (float64 each, plus one copy while joining)."""
        n_cols = len(columns if columns is not None else self.names)
        return 2 * 8 * n_cols * self.estimated_rows()


class CsvSource(RecordingSource):
    def __init__(self, path: str, name: str | None = None):
        """name: what messages call the file (default: its path)."""
        self._file = path
        self.path = path = name or path
        try:
            self.size_bytes = os.path.getsize(self._file)
            with open(self._file, "rb") as fh:
                head = fh.read(MAX_HEAD_BYTES + 1)
        except OSError as err:
            raise RecordingError(f"{path}: cannot read: {err.strerror or err}") from err
        at_eof = len(head) <= MAX_HEAD_BYTES
        parsed = _parse_head(head[:MAX_HEAD_BYTES], path, at_eof)
        self.metadata = parsed.metadata
        self.names = parsed.header
        self._header_line = parsed.header_line
        self._data_offset = parsed.data_offset
        self.form = _form_of(path, self.names, self.metadata, self._header_line)
        # rows per byte from the first data (for the memory estimate)
        sample = head[self._data_offset:]
        newlines = sample.count(b"\n")
        self._bytes_per_row = (len(sample) / newlines) if newlines else max(len(sample), 1)

    @property
    def progress_total(self):
        return self.size_bytes - self._data_offset, "B"

    def estimated_rows(self) -> int:
        return int((self.size_bytes - self._data_offset) / self._bytes_per_row) + 1

    def _blocks(self):
        return line_blocks(self._file, self.path, self._data_offset, self._header_line + 1)

    def chunks(self, columns=None, progress=None):
        import pyarrow as pa
        import pyarrow.csv as pacsv

        wanted = list(self.names) if columns is None else [c for c in self.names if c in columns]
        validator = _Validator(self.path, self.form)
        check_cols = set(wanted) | set(RAW_REQUIRED if self.form == "raw" else ("t_s",))
        check_cols &= set(self.names)
        read_cols = [c for c in self.names if c in check_cols]
        # one thread: with pyarrow's thread pool, a command that ended on a bad file aborted
        # at interpreter exit in 1 to 4 runs of 10 ("terminate called without an active
        # exception", exit 134 instead of 2; apache/arrow#34314). One core parses ~1 µs a row.
        read_opts = pacsv.ReadOptions(column_names=self.names, block_size=1 << 20, use_threads=False)
        convert = pacsv.ConvertOptions(
            column_types={n: pa.float64() for n in read_cols}, include_columns=read_cols,
            null_values=[""], strings_can_be_null=True, quoted_strings_can_be_null=True)
        for block, first_line, offset in self._blocks():
            self._check_lines(block, first_line, offset)
            try:
                table = pacsv.read_csv(pa.py_buffer(block), read_options=read_opts, convert_options=convert)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as err:
                raise self._locate(block, first_line, read_cols, err) from None
            cols = {n: table.column(n).to_numpy() for n in read_cols}
            if table.num_rows:
                # the row-to-line callback binds this block: it must not see the next one
                validator.check(cols, lambda i, block=block, first_line=first_line:
                                f"{self.path}:{self._line_of_row(block, first_line, i)}")
                yield {n: cols[n] for n in wanted}
            if progress is not None:
                progress.update(len(block))

    def _check_lines(self, block: bytes, first_line: int, offset: int) -> None:
        """UTF-8, cheaply: a full decode only of blocks that are not plain ASCII (the line
        length is checked by `line_blocks`)."""
        if not block.isascii():
            try:
                block.decode("utf-8")
            except UnicodeDecodeError as err:
                line = first_line + block.count(b"\n", 0, err.start)
                raise _error(self.path, line, None,
                             f"not UTF-8 text ({err.reason}) at byte offset {offset + err.start}") from None

    def _line_rows(self, block: bytes, first_line: int):
        """(line number, text) of each non-blank line of a block: the rows the parser saw."""
        text = block.decode("utf-8")
        for k, line in enumerate(text.split("\n")):
            if line.strip("\r").strip():
                yield first_line + k, line.rstrip("\r")

    def _line_of_row(self, block: bytes, first_line: int, row: int) -> int:
        for i, (line, _) in enumerate(self._line_rows(block, first_line)):
            if i == row:
                return line
        return first_line

    def _locate(self, block: bytes, first_line: int, read_cols: list[str], err) -> RecordingError:
        """The parser said no somewhere in this block: find the line and column, exactly."""
        import pyarrow as pa
        import pyarrow.csv as pacsv

        width = len(self.names)
        csv.field_size_limit(MAX_LINE_BYTES + 1)
        lines = list(self._line_rows(block, first_line))
        for line, text in lines:
            cells = next(csv.reader([text]))
            if len(cells) != width:
                truncated = line == lines[-1][0] and not block.endswith(b"\n")
                return _error(self.path, line, None, f"has {len(cells)} cells, the header has {width}"
                              + (" (the last line is cut short: a truncated file?)" if truncated else ""))
        # every row has its cells: some cell is not a number. The block again as text, each
        # column cast as the reader does; the first failing row by bisection (a few casts,
        # not one per cell: a 4 MiB block has ~65 000 rows)
        text = pacsv.read_csv(pa.py_buffer(block),
                              read_options=pacsv.ReadOptions(column_names=self.names, use_threads=False),
                              convert_options=pacsv.ConvertOptions(
                                  column_types={n: pa.string() for n in read_cols}, include_columns=read_cols,
                                  null_values=[""], strings_can_be_null=True, quoted_strings_can_be_null=True))
        first: tuple[int, int, str, str] | None = None  # (row, column's place, name, cell)
        import pyarrow.compute as pc

        for place, name in enumerate(read_cols):
            # the reader trims spaces around a number; a cast does not
            col = pc.utf8_trim_whitespace(text.column(name).combine_chunks())
            if _casts(col):
                continue
            lo, hi = 0, len(col)  # col[:lo] casts, col[:hi] does not
            while hi - lo > 1:
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if _casts(col.slice(0, mid)) else (lo, mid)
            if first is None or (lo, place) < first[:2]:
                first = (lo, place, name, col[lo].as_py())
        if first is not None:
            row, _, name, cell = first
            return _error(self.path, self._line_of_row(block, first_line, row), name,
                          f"{cell_text(cell)} is not a number")
        return _error(self.path, f"{first_line}-{lines[-1][0] if lines else first_line}", None,
                      f"cannot be read: {str(err).splitlines()[0]}")


def _casts(col) -> bool:
    """Whether pyarrow reads these texts as floats (its rules, not Python's float())."""
    import pyarrow as pa

    try:
        col.cast(pa.float64())
        return True
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return False


class ParquetSource(RecordingSource):
    def __init__(self, path: str):
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.path = path
        try:
            self.size_bytes = os.path.getsize(path)
            # pre_buffer (pyarrow's default) keeps the file's compressed column chunks once
            # read: ~15 bytes per sample, 650 MB peak for a streamed 12-hour estimate
            self._file = pq.ParquetFile(path, pre_buffer=False)
        except OSError as err:
            raise RecordingError(f"{path}: cannot read: {err.strerror or err}") from err
        except (pa.ArrowInvalid, pa.ArrowException) as err:
            raise RecordingError(f"{path}: not a complete Parquet file (truncated or partly written?): "
                                 f"{str(err).splitlines()[0]}") from None
        schema = self._file.schema_arrow
        raw_meta = schema.metadata or {}
        self.metadata = {}
        for k, v in raw_meta.items():
            key = k.decode("utf-8", "replace")
            if key.startswith("ARROW:") or key == "pandas":
                continue
            self.metadata[key] = v.decode("utf-8", "replace")
        self.names = list(schema.names)
        for f in schema:
            if not (pa.types.is_integer(f.type) or pa.types.is_floating(f.type) or pa.types.is_boolean(f.type)):
                raise _error(path, "header", f.name, f"has type {f.type}, not a number")
        self.form = _form_of(path, self.names, self.metadata, "header")

    @property
    def progress_total(self):
        return self._file.metadata.num_rows, " rows"

    def estimated_rows(self) -> int:
        return self._file.metadata.num_rows

    def chunks(self, columns=None, progress=None):
        import pyarrow as pa

        wanted = list(self.names) if columns is None else [c for c in self.names if c in columns]
        validator = _Validator(self.path, self.form)
        must = set(RAW_REQUIRED if self.form == "raw" else ("t_s",))
        read_cols = [c for c in self.names if c in set(wanted) | must]
        start = 0
        try:
            for batch in self._file.iter_batches(batch_size=PARQUET_BATCH_ROWS, columns=read_cols,
                                                 use_threads=False):  # see CsvSource.chunks
                cols = {}
                for n in read_cols:
                    arr = batch.column(n).cast(pa.float64())
                    cols[n] = arr.fill_null(math.nan).to_numpy() if arr.null_count else arr.to_numpy()
                validator.check(cols, lambda i, base=start: f"{self.path}: row {base + i + 1}")
                start += batch.num_rows
                yield {n: cols[n] for n in wanted}
                if progress is not None:
                    progress.update(batch.num_rows)
        except (pa.ArrowInvalid, pa.ArrowException, OSError) as err:
            raise RecordingError(f"{self.path}: row {start + 1}…: cannot be read (truncated or damaged Parquet?): "
                                 f"{str(err).splitlines()[0]}") from None


def open_recording(path: str | os.PathLike) -> RecordingSource:
    path = str(path)
    return ParquetSource(path) if is_parquet(path) else CsvSource(path)


def available_memory_bytes() -> int | None:
    """MemAvailable of /proc/meminfo (None where unknown: no refusal then)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError):
        return None
    return None


def check_fits_in_memory(path: str, needed_bytes: int, what: str) -> None:
    """Refuse (exit 2) what would exhaust the machine, instead of being killed half way."""
    avail = available_memory_bytes()
    if avail is not None and needed_bytes > avail:
        raise RecordingError(f"{path}: {what} needs about {needed_bytes / 1e9:.2f} GB of memory, the machine has "
                             f"{avail / 1e9:.2f} GB available")


def read_recording(path: str | os.PathLike) -> Recording:
    """The whole recording in memory (refused with a clear message when it cannot fit)."""
    return read_all(open_recording(path))


def read_all(source: RecordingSource, columns: list[str] | None = None, progress=None) -> Recording:
    """Every chunk of an open recording joined (refused when it cannot fit in memory)."""
    check_fits_in_memory(source.path, source.whole_file_bytes(columns), "reading the whole recording")
    if isinstance(source, ParquetSource):
        # the row count is known: fill preallocated columns (no second copy while joining)
        n = source.estimated_rows()
        cols: dict[str, np.ndarray] | None = None
        at = 0
        for chunk in source.chunks(columns, progress=progress):
            if cols is None:
                cols = {name: np.empty(n) for name in chunk}
            k = len(next(iter(chunk.values())))
            for name, col in chunk.items():
                cols[name][at:at + k] = col
            at += k
        if not at:
            raise RecordingError(f"{source.path}: no data rows")
        return Recording(source.path, source.metadata, cols, source.form)
    parts: dict[str, list[np.ndarray]] = {}
    for chunk in source.chunks(columns, progress=progress):
        for name, col in chunk.items():
            parts.setdefault(name, []).append(col)
    if not parts:
        raise RecordingError(f"{source.path}: no data rows")
    cols = {name: (p[0] if len(p) == 1 else np.concatenate(p)) for name, p in parts.items()}
    return Recording(source.path, source.metadata, cols, source.form)


def parse_recording(text: str, path: str = "<recording>") -> Recording:
    """A recording from text in memory (tests, other tools): the same reader as for files."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "recording.csv"
        f.write_bytes(text.encode("utf-8"))
        return read_all(CsvSource(str(f), name=path))


# ---- SI units ------------------------------------------------------------------------------


def _axis_of(path: str, metadata: dict[str, str]) -> str:
    axis = metadata.get("axis", "x").strip().lower()
    if axis not in ("x", "y"):
        raise RecordingError(f"{path}: metadata axis={axis!r} must be 'x' or 'y'")
    return axis


def _acc_range_mps2(path: str, metadata: dict[str, str]) -> float:
    text = metadata.get("acc_range_mps2")
    if text is None:
        return DEFAULT_ACC_RANGE_MPS2
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise RecordingError(f"{path}: metadata acc_range_mps2={text!r} is not a positive number")
    return value


class AccelerationConverter:
    """Either form's chunks → AccelerationSeries chunks, with what carries between them."""

    def __init__(self, path: str, form: str, metadata: dict[str, str], calibration: Calibration | None = None):
        self.path = path
        self.form = form
        self.axis = _axis_of(path, metadata)
        self.report = InputReport()
        if form == "raw":
            self._raw = RawChunkConverter(float(metadata["tick_hz"]), calibration or calibration_from(path, metadata),
                                          SensorParams().range_g)
            self.report.sequence = self._raw.report
            self.report.impossible_limit_mps2 = self._raw.limit_mps2
        else:
            self._limit = _acc_range_mps2(path, metadata)
            self.report.impossible_limit_mps2 = self._limit

    def convert(self, c: dict[str, np.ndarray]) -> AccelerationSeries:
        main, other = ("x", "y") if self.axis == "x" else ("y", "x")
        if self.form == "raw":
            flags = (np.nan_to_num(c["flags"], nan=0.0).astype(np.int64) if "flags" in c
                     else np.zeros(c["seq"].size, np.int64))
            try:
                ch = self._raw.convert(c["seq"].astype(np.int64), c["t1x"], c["t1y"], c["t2"], flags)
            except ValueError as err:
                raise RecordingError(f"{self.path}: {err}") from err
            self.report.impossible += ch.impossible[main]
            t_s, lost = ch.t_s, ch.lost_before
            acc_main, acc_other, valid_main = ch.acc_mps2[main], ch.acc_mps2[other], ch.valid[main]
        else:
            t_s = c["t_s"]
            lost = np.zeros(t_s.size, dtype=np.int64)
            acc_main = c["acc_x_mps2"] if self.axis == "x" or "acc_y_mps2" not in c else c["acc_y_mps2"]
            acc_other = c.get("acc_y_mps2") if self.axis == "x" else c.get("acc_x_mps2")
            finite = np.isfinite(acc_main)
            valid_main = finite & (np.abs(acc_main) <= self._limit)
            self.report.impossible += int(np.count_nonzero(finite & ~valid_main))
            if acc_other is not None:
                acc_other = np.where(np.abs(acc_other) <= self._limit, acc_other, np.nan)
        reference = {k: c[k] for k in REFERENCE_COLUMNS if k in c}
        return AccelerationSeries(
            t_s=t_s,
            acc_mps2=np.where(valid_main, acc_main, np.nan),
            valid=valid_main,
            lost_before=lost,
            other_axis_mps2=acc_other,
            reference=reference,
            temp_c=c.get("temp_c"),
            t_host_s=c.get("t_host_s"),
            axis=self.axis,
            report=self.report,
            standstill_hint=c.get(HINT_COLUMN),
        )


def to_acceleration(rec: Recording, calibration: Calibration | None = None) -> AccelerationSeries:
    """Either form → sample time and acceleration along the measured axis."""
    series = AccelerationConverter(rec.path, rec.form, rec.metadata, calibration).convert(rec.columns)
    # a reference column that is empty throughout is not a reference
    series.reference = {k: v for k, v in series.reference.items() if rec.has(k)}
    return series


def acceleration_chunks(source: RecordingSource, columns: list[str] | None = None, progress=None,
                        calibration: Calibration | None = None) -> Iterator[AccelerationSeries]:
    """The recording as AccelerationSeries chunks (the streamed commands); each chunk's
    report is the running one, complete after the last chunk."""
    conv = AccelerationConverter(source.path, source.form, source.metadata, calibration)
    chunks = source.chunks(columns, progress=progress)
    try:
        for chunk in chunks:
            yield conv.convert(chunk)
    finally:
        # now, not whenever the garbage collector gets to it: a reader left suspended
        # until interpreter exit can abort the process in pyarrow's teardown (exit 134)
        chunks.close()


# ---- writing -------------------------------------------------------------------------------


def _csv_header(names: list[str]) -> str:
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(names)
    return out.getvalue()


def _polars():
    """polars, imported when first needed. Its import checks the CPU's features by running
    a few bytes it writes into memory; where memory that was writable may not become
    executable (systemd's MemoryDenyWriteExecute, as numba meets it: gateway/core/jit.py)
    that check cannot run, and is skipped then: on a CPU without the features the wheel
    was built for, writing a CSV would then stop with an illegal instruction instead of
    polars' clear message (checked on this machine kind only: it has them)."""
    try:
        import polars
    except RuntimeError:
        for name in [m for m in sys.modules if m == "polars" or m.startswith("polars.")]:
            del sys.modules[name]
        os.environ["POLARS_SKIP_CPU_CHECK"] = "1"
        import polars
    return polars


class ColumnWriter:
    """Columns written chunk by chunk to CSV or Parquet (by the path's extension), atomically:
    into a temporary file beside the target, renamed over it by commit(); abort() (or an
    exception inside a with-block) leaves no file, so a reader never sees half a file.

    metadata: the recording's `# key=value` lines (CSV) / key-value metadata (Parquet);
    None writes a plain table (estimate's output). integer_columns are written as integers.
    """

    def __init__(self, path: str | os.PathLike, names: list[str], metadata: dict[str, str] | None,
                 integer_columns=INTEGER_COLUMNS):
        import pyarrow as pa

        check_output(path)
        self.path = Path(path)
        self.names = list(names)
        self.parquet = is_parquet(path)
        self.rows = 0
        self._tmp = self.path.with_name(f".{self.path.name}.tmp{os.getpid()}")
        ints = set(integer_columns)
        self._schema = pa.schema(
            [pa.field(n, pa.int64() if n in ints else pa.float64()) for n in self.names],
            metadata=None if metadata is None else {str(k): str(v) for k, v in metadata.items()},
        )
        self._writer = None
        self._fh = None
        try:
            if self.parquet:
                import pyarrow.parquet as pq

                # lz4 and no dictionary for the float columns: a 12-hour file writes and reads
                # in a few seconds on one core (zstd and dictionaries took ~2× as long)
                self._writer = pq.ParquetWriter(str(self._tmp), self._schema, compression="lz4",
                                                use_dictionary=[n for n in self.names if n in ints])
            else:
                self._fh = open(self._tmp, "wb")  # noqa: SIM115 - open across write() calls; closed in close()/abort()
                head = "".join(f"# {k}={_one_line(v)}\n" for k, v in (metadata or {}).items())
                self._fh.write((head + _csv_header(self.names)).encode("utf-8"))
        except OSError as err:
            self.abort()
            raise RecordingError(f"{path}: cannot write: {err.strerror or err}") from err

    def write(self, columns: dict[str, np.ndarray]) -> None:
        import pyarrow as pa

        arrays = []
        for f in self._schema:
            col = np.asarray(columns[f.name])
            if pa.types.is_integer(f.type):
                colf = col.astype(float, copy=False)
                missing = ~np.isfinite(colf)
                arr = pa.array(np.where(missing, 0, colf).astype(np.int64), mask=missing if missing.any() else None)
            else:
                colf = col.astype(float, copy=False)
                missing = ~np.isfinite(colf)  # empty cell: NaN and ±inf are "no value" in a recording
                arr = pa.array(colf, mask=missing if missing.any() else None)
            arrays.append(arr)
        batch = pa.record_batch(arrays, schema=self._schema if self.parquet else self._schema.remove_metadata())
        try:
            if self.parquet:
                self._writer.write_batch(batch)
            else:
                # polars formats floats (shortest round-trip, ryu) ~2.5x as fast as pyarrow's
                # CSV writer on one core: most of a 12-hour CSV output's time
                _polars().from_arrow(batch).write_csv(self._fh, include_header=False, null_value="")
        except OSError as err:
            self.abort()
            raise RecordingError(f"{self.path}: cannot write: {err.strerror or err}") from err
        self.rows += batch.num_rows

    def commit(self) -> None:
        try:
            if self._writer is not None:
                self._writer.close()
            if self._fh is not None:
                self._fh.close()
            os.replace(self._tmp, self.path)
        except OSError as err:
            self.abort()
            raise RecordingError(f"{self.path}: cannot write: {err.strerror or err}") from err

    def abort(self) -> None:
        for closer in (self._writer, self._fh):
            try:
                if closer is not None:
                    closer.close()
            except Exception:  # noqa: BLE001 - already failing; the temporary file goes anyway
                pass
        self._tmp.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, _tb):
        if exc_type is None:
            self.commit()
        else:
            self.abort()
        return False


def _one_line(value) -> str:
    return str(value).replace("\r", " ").replace("\n", " ")


WRITE_CHUNK_ROWS = 1 << 20


def write_recording(path: str | os.PathLike, metadata: dict[str, str], columns: dict[str, np.ndarray],
                    progress=None) -> None:
    """Write atomically (CSV or Parquet by extension): a reader never sees half a file."""
    names = list(columns)
    meta = {"format": FORMAT_ID, **{k: v for k, v in metadata.items() if k != "format"}}
    n = len(next(iter(columns.values()))) if columns else 0
    with ColumnWriter(path, names, meta) as w:
        for start in range(0, max(n, 1), WRITE_CHUNK_ROWS):
            w.write({k: np.asarray(v)[start:start + WRITE_CHUNK_ROWS] for k, v in columns.items()})
            if progress is not None:
                progress.update(min(WRITE_CHUNK_ROWS, n - start))


class RecordingWriter:
    """Streams rows to a file as they arrive (for `adxlgw record`).

    CSV: each row goes to the file as it comes (flush() puts it on disk), so a recorder
    killed mid-run leaves every row before the kill. Parquet: rows are kept and written
    as row groups; the file appears only at close() (a killed recorder leaves none)."""

    PARQUET_GROUP_ROWS = 1 << 16

    def __init__(self, path: str | os.PathLike, metadata: dict[str, str], names: list[str]):
        self.path = str(path)
        self.names = names
        self.rows = 0
        self._parquet = is_parquet(path)
        if self._parquet:
            self._out = ColumnWriter(path, names, {"format": FORMAT_ID, **metadata})
            self._pending: list[dict] = []
            return
        try:
            self._fh = open(path, "w", encoding="utf-8", newline="")  # noqa: SIM115 - open across write_row(); closed in close()
        except OSError as err:
            raise RecordingError(f"{path}: cannot write: {err.strerror or err}") from err
        for key, value in {"format": FORMAT_ID, **metadata}.items():
            self._fh.write(f"# {key}={_one_line(value)}\n")
        self._fh.write(_csv_header(names))

    def write_row(self, values: dict[str, object]) -> None:
        self.rows += 1
        if self._parquet:
            self._pending.append(values)
            if len(self._pending) >= self.PARQUET_GROUP_ROWS:
                self._flush_group()
            return
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

    def _flush_group(self) -> None:
        if self._pending:
            cols = {n: np.array([np.nan if r.get(n) is None else float(r[n]) for r in self._pending])
                    for n in self.names}
            self._out.write(cols)
            self._pending = []

    def flush(self) -> None:
        if not self._parquet:
            self._fh.flush()

    def close(self) -> None:
        if self._parquet:
            self._flush_group()
            self._out.commit()
        else:
            self._fh.close()
