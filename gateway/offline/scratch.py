"""Long series kept on disk between the passes of a streamed command (fit-drift), so that
memory follows the chunk, not the recording."""
from __future__ import annotations

import tempfile
from collections.abc import Iterator

import numpy as np

from gateway.core.drift_fit import BLOCK_SAMPLES

_ITEM_BYTES = np.dtype(np.float64).itemsize


class FileStore:
    """A float64 series in an unnamed temporary file (gone when closed or the process ends):
    appended in chunks, read back by range (gateway/core/drift_fit.SeriesStore)."""

    def __init__(self, directory: str | None = None) -> None:
        self._file = tempfile.TemporaryFile(dir=directory)  # noqa: SIM115 - kept open across appends; closed in close()
        self.size = 0

    def append(self, values: np.ndarray) -> None:
        self._file.seek(0, 2)
        np.ascontiguousarray(values, dtype=np.float64).tofile(self._file)
        self.size += int(np.size(values))

    def read(self, start: int, count: int) -> np.ndarray:
        self._file.seek(start * _ITEM_BYTES)
        return np.fromfile(self._file, dtype=np.float64, count=max(0, min(count, self.size - start)))

    def blocks(self, block: int = BLOCK_SAMPLES) -> Iterator[np.ndarray]:
        for start in range(0, self.size, block):
            yield self.read(start, block)

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> FileStore:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
