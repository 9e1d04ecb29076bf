"""Recording files (shared/spec/recording-format.md): the public API (being split into
modules; everything is in .sources for now)."""
from gateway.offline.recording.sources import *  # noqa: F403
from gateway.offline.recording.sources import (  # noqa: F401 - the names callers use, private ones included
    BLOCK_BYTES,
    MAX_LINE_BYTES,
    PARQUET_BATCH_ROWS,
)
