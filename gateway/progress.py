"""Progress bars for the long offline commands: on stderr when it is a terminal, else nothing.

tqdm decides (disable=None: off when stderr is not a TTY), so logs and pipes stay clean.
"""
from __future__ import annotations

import sys

from tqdm import tqdm


def progress_bar(total: int | None, what: str, unit: str = "B"):
    """A bar with update(n) and close(); a context manager. Bytes are shown as kB/MB/GB."""
    return tqdm(total=total, desc=what, unit=unit.strip() or "it", unit_scale=True,
                unit_divisor=1024 if unit == "B" else 1000, file=sys.stderr, disable=None,
                leave=False, dynamic_ncols=True)


def reading_bar(source, what: str = "reading"):
    """The bar for reading a recording (its bytes for CSV, its rows for Parquet)."""
    total, unit = source.progress_total
    return progress_bar(total, f"{what} {source.path}", unit)
