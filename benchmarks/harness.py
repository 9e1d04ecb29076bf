"""What every benchmark shares: its arguments' common part, the lines that say what ran
where (command, date, machine — printed with every result), and the results as JSON
beside the printed table.

    parser = harness.parser(__doc__)          # argparse with --json PATH
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    harness.stamp(__spec__.name)              # command, date, machine
    ... print the table ...
    harness.write_json(args, {"rows": rows})  # when --json was given
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
from pathlib import Path

from gateway.core.jit import JIT_ENABLED


def machine() -> str:
    """CPU model, cores, Python, whether numba compiles: one line."""
    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, numba {'on' if JIT_ENABLED else 'off'}"


def parser(doc: str | None) -> argparse.ArgumentParser:
    """An argument parser showing the module's docstring, with --json."""
    made = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    made.add_argument("--json", type=Path, metavar="PATH", help="write the results here too, as JSON")
    return made


def stamp(module: str, argv: list[str] | None = None) -> dict[str, str]:
    """Prints the command that reproduces this run, the date and the machine; returns them
    (for the JSON)."""
    args = sys.argv[1:] if argv is None else argv
    lines = {
        "command": " ".join([".venv/bin/python -m", module, *args]),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": machine(),
    }
    for key, value in lines.items():
        print(f"{key}: {value}")
    return lines


def write_json(args: argparse.Namespace, results: object, run: dict[str, str] | None = None) -> None:
    """Writes `results` (with the stamp's lines under "run") to --json, if given."""
    if getattr(args, "json", None) is None:
        return
    document = {"run": run or {}, "results": results}
    Path(args.json).write_text(json.dumps(document, indent=1, default=str) + "\n", encoding="utf-8")
