"""One line that says what machine a benchmark ran on (printed with every result)."""
from __future__ import annotations

import os
import platform
from pathlib import Path

from gateway.core.jit import JIT_ENABLED


def machine() -> str:
    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numba {'on' if JIT_ENABLED else 'off'}"
