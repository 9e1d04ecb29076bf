"""Peak memory of `adxlgw import` against the size of the file, side by side across checkouts.

    .venv/bin/python -m benchmarks.speed.import_memory [--mb 50,200] [--root today=/path/to/checkout ...]

Writes seeded CSV logger files of each --mb size (a time column in ms, an acceleration in g
and a position reference: 2 ms rows, the shape of a 500 Hz log) into a fresh directory
under /tmp, then runs `python -m gateway.cli import FILE --time-col … --out OUT.csv` from
each checkout (this one as "this", and every --root NAME=PATH: its own `gateway/` on the
path, this venv's libraries) as a fresh process, one at a time, and prints its peak
memory (the child's maximum RSS from wait4) and CPU time. The goal (issue 31): at most
400 MB, flat with the file's size. The files are deleted at the end.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import harness

ROOT = Path(__file__).resolve().parents[2]

ROWS_PER_WRITE = 200_000


def write_log(path: Path, megabytes: float, seed: int = 0) -> int:
    """A logger's CSV of about `megabytes` MB; returns its rows."""
    rng = np.random.default_rng(seed)
    rows = 0
    with open(path, "w") as fh:
        fh.write("t_ms,acc_g,pos_mm\n")
        while fh.tell() < megabytes * 1e6:
            k = rows + np.arange(ROWS_PER_WRITE)
            t_ms = 2.0 * k
            np.savetxt(fh, np.column_stack([t_ms, rng.normal(0.0, 0.002, k.size), 300 * np.sin(t_ms / 1e3)]),
                       fmt="%.1f,%.6f,%.4f")
            rows += k.size
    return rows


def import_peak(root: Path, src: Path, out: Path) -> tuple[float, float, int]:
    """(peak RSS MB, CPU s, exit code) of one import from the checkout at `root`."""
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "import", str(src), "--time-col", "t_ms",
                             "--time-unit", "ms", "--acc-col", "acc_g", "--acc-unit", "g", "--ref-pos-col",
                             "pos_mm", "--ref-unit", "mm", "--out", str(out)],
                            cwd=root, env={**os.environ, "PYTHONPATH": str(root)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    return usage.ru_maxrss / 1024, usage.ru_utime + usage.ru_stime, os.waitstatus_to_exitcode(status)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mb", default="50,200", help="file sizes, MB (comma-separated)")
    ap.add_argument("--root", action="append", default=[], metavar="NAME=PATH")
    args = ap.parse_args()
    roots = {"this": ROOT, **{n: Path(p) for n, p in (r.split("=", 1) for r in args.root)}}
    work = Path(tempfile.mkdtemp(prefix="adxlgw-import-memory-"))
    try:
        harness.stamp("benchmarks.speed.import_memory")
        print(f"load average {os.getloadavg()[0]:.2f}")
        print("| checkout | file, MB | rows | peak RSS, MB | CPU, s | exit |")
        print("| --- | --- | --- | --- | --- | --- |")
        for mb in (float(m) for m in args.mb.split(",")):
            src = work / f"log-{mb:g}.csv"
            rows = write_log(src, mb)
            for name, root in roots.items():
                peak, cpu, code = import_peak(root, src, work / "out.csv")
                print(f"| {name} | {src.stat().st_size / 1e6:.0f} | {rows} | {peak:.0f} | {cpu:.1f} | {code} |",
                      flush=True)
            src.unlink()
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
