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

The package's modules, and this one as the public API every caller uses:
- `format`: the columns, the two forms, `Recording`, a CSV head and a chunk's checks;
- `sources`: the readers (`open_recording`, `read_all`, `read_recording`, `line_blocks`);
- `acceleration`: either form in SI units (`to_acceleration`, `acceleration_chunks`);
- `writing`: `write_recording`, `ColumnWriter`, `RecordingWriter`, `check_output`.
"""
from gateway.offline.recording.acceleration import (
    AccelerationConverter,
    AccelerationSeries,
    InputReport,
    acceleration_chunks,
    to_acceleration,
)
from gateway.offline.recording.format import (
    ACC_REQUIRED,
    FORMAT_ID,
    HINT_COLUMN,
    INTEGER_COLUMNS,
    MAX_HEAD_BYTES,
    MAX_LINE_BYTES,
    PARQUET_SUFFIXES,
    RAW_REQUIRED,
    REFERENCE_COLUMNS,
    Recording,
    calibration_from,
    cell_text,
    is_parquet,
)
from gateway.offline.recording.sources import (
    CsvSource,
    ParquetSource,
    RecordingSource,
    available_memory_bytes,
    check_fits_in_memory,
    line_blocks,
    open_recording,
    parse_recording,
    read_all,
    read_recording,
)
from gateway.offline.recording.writing import (
    OUTPUT_SUFFIXES,
    ColumnWriter,
    RecordingWriter,
    check_output,
    write_recording,
)

__all__ = [
    "ACC_REQUIRED", "FORMAT_ID", "HINT_COLUMN", "INTEGER_COLUMNS", "MAX_HEAD_BYTES", "MAX_LINE_BYTES",
    "OUTPUT_SUFFIXES", "PARQUET_SUFFIXES", "RAW_REQUIRED", "REFERENCE_COLUMNS",
    "AccelerationConverter", "AccelerationSeries", "ColumnWriter", "CsvSource", "InputReport", "ParquetSource",
    "Recording", "RecordingSource", "RecordingWriter",
    "acceleration_chunks", "available_memory_bytes", "calibration_from", "cell_text", "check_fits_in_memory",
    "check_output", "is_parquet", "line_blocks", "open_recording", "parse_recording", "read_all",
    "read_recording", "to_acceleration", "write_recording",
]
