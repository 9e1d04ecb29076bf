"""Reading recordings as a stream of chunks: CSV in blocks of whole lines parsed by pyarrow,
Parquet in row batches; every chunk checked (format.ChunkValidator) before it is handed on,
so memory follows the chunk, not the file. `read_all` joins the chunks for the commands
that need every sample at once (refused when it cannot fit in memory)."""
from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from gateway.errors import RecordingError
from gateway.offline.recording.format import (
    MAX_HEAD_BYTES,
    MAX_LINE_BYTES,
    RAW_REQUIRED,
    ChunkValidator,
    Recording,
    cell_text,
    form_of,
    is_parquet,
    located_error,
    parse_head,
)

# bytes handed to the CSV parser at a time (~65 000 rows), rows per Parquet batch: large
# enough that the per-chunk Python work is noise, small enough that a streamed estimate
# peaks under 400 MB (measured: 16 MB blocks and 2^19-row batches peaked at ~570 MB,
# and were no faster)
BLOCK_BYTES = 4 << 20
PARQUET_BATCH_ROWS = 1 << 17


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
                    raise located_error(name, line, None, f"line longer than {MAX_LINE_BYTES} bytes")
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
            raise located_error(name, first_line + k, None,
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
        parsed = parse_head(head[:MAX_HEAD_BYTES], path, at_eof)
        self.metadata = parsed.metadata
        self.names = parsed.header
        self._header_line = parsed.header_line
        self._data_offset = parsed.data_offset
        self.form = form_of(path, self.names, self.metadata, self._header_line)
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
        validator = ChunkValidator(self.path, self.form)
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
                raise located_error(self.path, line, None,
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
                return located_error(self.path, line, None, f"has {len(cells)} cells, the header has {width}"
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
            return located_error(self.path, self._line_of_row(block, first_line, row), name,
                          f"{cell_text(cell)} is not a number")
        return located_error(self.path, f"{first_line}-{lines[-1][0] if lines else first_line}", None,
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
                raise located_error(path, "header", f.name, f"has type {f.type}, not a number")
        self.form = form_of(path, self.names, self.metadata, "header")

    @property
    def progress_total(self):
        return self._file.metadata.num_rows, " rows"

    def estimated_rows(self) -> int:
        return self._file.metadata.num_rows

    def chunks(self, columns=None, progress=None):
        import pyarrow as pa

        wanted = list(self.names) if columns is None else [c for c in self.names if c in columns]
        validator = ChunkValidator(self.path, self.form)
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

