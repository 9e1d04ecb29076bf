"""Writing recordings: CSV or Parquet by the extension, atomically (a reader never sees
half a file), whole or row by row (`adxlgw record`)."""
from __future__ import annotations

import csv
import io
import math
import os
import sys
from pathlib import Path

import numpy as np

from gateway.errors import InputError, RecordingError
from gateway.offline.recording.format import FORMAT_ID, INTEGER_COLUMNS, PARQUET_SUFFIXES, is_parquet

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
