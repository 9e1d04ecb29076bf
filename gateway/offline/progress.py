"""Progress bars for the long offline commands: on stderr when it is a terminal, else nothing.

Off when stderr is not a terminal, so logs and pipes stay clean.
"""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

from tqdm import tqdm


def progress_bar(total: int | None, what: str, unit: str = "B"):
    """A bar with update(n) and close(); a context manager. Bytes are shown as kB/MB/GB."""
    # a terminal that reports no size (0×0: some ptys) would get an empty bar: tqdm hides
    # bars below the screen's last row, and takes such a screen as −1 rows
    size = shutil.get_terminal_size((80, 24))
    return tqdm(total=total, desc=what, unit=unit.strip() or "it", unit_scale=True,
                unit_divisor=1024 if unit == "B" else 1000, file=sys.stderr, disable=None,
                leave=False, ncols=size.columns, nrows=size.lines)


def reading_bar(source, what: str = "reading"):
    """The bar for reading a recording (its bytes for CSV, its rows for Parquet)."""
    total, unit = source.progress_total
    return progress_bar(total, f"{what} {Path(source.path).name}", unit)
