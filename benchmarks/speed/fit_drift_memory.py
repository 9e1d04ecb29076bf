"""Peak memory of `adxlgw fit-drift` against the size of the file, side by side across checkouts.

    .venv/bin/python -m benchmarks.speed.fit_drift_memory [--mb 50,200] [--root before=/path/to/checkout ...]

Writes a seeded standstill recording in the acceleration form of each --mb size (t_s and
acc_x_mps2 at 2 ms, white noise on a slow exponential drift: what the paper's 12-hour
record looks like, shorter) into a fresh directory under /tmp, then runs
`python -m gateway.cli fit-drift FILE --plot P.png` from each checkout (this one as "this",
and every --root NAME=PATH: its own `gateway/` on the path, this venv's libraries) as a fresh
process, one at a time, and prints its peak memory (the child's maximum RSS from wait4), its
CPU time and the fitted C1, T. The goal (issue 31): at most 400 MB, flat with the file's
size, the same fit. The files are deleted at the end (the streamed fit keeps ~24 bytes a
sample in unnamed temporary files while it runs).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.harness import parser, stamp, write_json
from gateway.offline.recording import ColumnWriter

ROOT = Path(__file__).resolve().parents[2]
ROWS_PER_WRITE = 500_000
PERIOD_S = 0.002


def write_standstill(path: Path, megabytes: float, seed: int = 0) -> int:
    """A standstill recording of about `megabytes` MB (through the project's writer); returns its rows."""
    rng = np.random.default_rng(seed)
    rows = 0
    with ColumnWriter(path, ["t_s", "acc_x_mps2"], {"source": "benchmark", "axis": "x"}) as out:
        while rows * _row_bytes(rows) < megabytes * 1e6:
            t = (rows + np.arange(ROWS_PER_WRITE)) * PERIOD_S
            acc = 0.1 + 0.03 * -np.expm1(-t / 900.0) + rng.normal(0.0, 0.02, t.size)
            out.write({"t_s": np.round(t, 6), "acc_x_mps2": np.round(acc, 6)})
            rows += t.size
    return rows


def _row_bytes(rows: int) -> float:
    """About what a row takes in the CSV at this length of record (shortest round-trip floats,
    as the writer prints them; the time's digits grow)."""
    return len(f"{round(rows * PERIOD_S, 6)!r},0.123456\n")


def fit_peak(root: Path, src: Path, plot: Path) -> tuple[float, float, int, str]:
    """(peak RSS MB, CPU s, exit code, "C1 …, T …") of one fit-drift from the checkout at `root`."""
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "fit-drift", str(src), "--plot", str(plot)],
                            cwd=root, env={**os.environ, "PYTHONPATH": str(root)},
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    found = [m.group(0) for m in re.finditer(r"(C1|T) += [^±]+± \S+ \w+", out)]
    return usage.ru_maxrss / 1024, usage.ru_utime + usage.ru_stime, os.waitstatus_to_exitcode(status), \
        "; ".join(found)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument("--mb", default="50,200", help="file sizes, MB (comma-separated)")
    ap.add_argument("--root", action="append", default=[], metavar="NAME=PATH")
    args = ap.parse_args()
    roots = {"this": ROOT, **{n: Path(p) for n, p in (r.split("=", 1) for r in args.root)}}
    run = stamp("benchmarks.speed.fit_drift_memory")
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    work = Path(tempfile.mkdtemp(prefix="adxlgw-fit-drift-memory-"))
    rows_out = []
    try:
        print("| checkout | file, MB | rows | peak RSS, MB | CPU, s | exit | fit |")
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for mb in (float(m) for m in args.mb.split(",")):
            src = work / f"still-{mb:g}.csv"
            rows = write_standstill(src, mb)
            for name, root in roots.items():
                peak, cpu, code, fit = fit_peak(root, src, work / "drift.png")
                size_mb = src.stat().st_size / 1e6
                print(f"| {name} | {size_mb:.0f} | {rows} | {peak:.0f} | {cpu:.1f} | {code} | {fit} |", flush=True)
                rows_out.append({"checkout": name, "file_mb": size_mb, "rows": rows, "peak_rss_mb": peak,
                                 "cpu_s": cpu, "exit": code, "fit": fit})
            src.unlink()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    write_json(args, rows_out, run)


if __name__ == "__main__":
    main()
