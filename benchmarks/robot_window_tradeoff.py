"""Could a shorter standstill window catch the robot's 0.08 s stop? (design file only)

    PYTHONPATH=. .venv/bin/python benchmarks/robot_window_tradeoff.py [--windows-s 0.05 0.07 0.1 0.15]

The realtime estimate's worst move on the design file is set by the 0.08 s stop, which no
0.1 s window fits inside (docs/estimation.md, "Limits"). The
window is an application choice (`EstimatorSettings.standstill_window_s`); this runs the
design file read as `estimate_benchmark.robot_run` reads it with other windows, every
other setting as `adxlgw estimate` picks it, and prints per window and method the
per-move errors, the worst move, the rest ends inside ±3σ and the time flagged "not
trustworthy". It measures the trade-off; it changes no default. The held-out file is
not run (datasets/README.md).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from benchmarks.machine_info import machine  # noqa: E402
from gateway.commands.estimate import settings_for  # noqa: E402
from gateway.core import estimator_kernel as K  # noqa: E402
from gateway.core.estimator import estimate_series  # noqa: E402
from gateway.core.evaluation import move_errors  # noqa: E402
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G  # noqa: E402
from gateway.offline.recording import AccelerationSeries  # noqa: E402

DESIGN_FILE = "eV50p_MPU6050RM3100.csv"
METHODS = (("realtime", False), ("realtime", True), ("smoothed", False), ("smoothed", True))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--windows-s", type=float, nargs="+", default=[0.05, 0.07, 0.1, 0.15])
    args = ap.parse_args()
    d = np.genfromtxt(REPO / "datasets" / "leiria-robot" / DESIGN_FILE, delimiter=",", names=True)
    t = d["sensor_time_s"] - d["sensor_time_s"][0]
    acc = d["acc_z_g"] * G
    ref, hint = d["ref_z_m"], d["robot_at_rest"]
    series = AccelerationSeries(t_s=t, acc_mps2=acc, valid=np.isfinite(acc), lost_before=np.zeros(t.size, np.int64))
    base = settings_for(series, "acceleration", "auto", None)
    print("command: PYTHONPATH=. .venv/bin/python benchmarks/robot_window_tradeoff.py --windows-s "
          + " ".join(f"{w:g}" for w in args.windows_s))
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    print(f"file:    {DESIGN_FILE}, sensor clock, median period {np.median(np.diff(t)) * 1e3:.2f} ms")
    print()
    first_move_s = float(t[np.flatnonzero(hint < 0.5)[0]])
    print("| window | method | hint | per move (%) | worst move | rest ends inside ±3σ | time flagged not trustworthy "
          "| first flagged at | stops accepted after the first move began |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for window_s in args.windows_s:
        settings = dataclasses.replace(base, standstill_window_s=window_s)
        for method, use_hint in METHODS:
            track = estimate_series(t, acc, method=method, settings=settings,
                                    standstill_hint=hint if use_hint else None)
            moves = move_errors(track.pos_m, ref, hint)
            ends = np.array([m.end for m in moves])
            inside = int(np.count_nonzero(np.abs(track.pos_m[ends] - ref[ends]) <= 3 * track.pos_std_m[ends]))
            per_move = ", ".join(f"{100 * m.error_m / abs(m.ref_m):+.1f}" for m in moves)
            flagged = np.flatnonzero(track.untrusted)
            first_flag = f"{t[flagged[0]]:.2f} s" if flagged.size else "never"
            stops = int(np.count_nonzero((track.flags & K.F_ENTRY).astype(bool) & (t > first_move_s)))
            print(f"| {window_s:g} s ({settings.window_samples} samples) | {method} | {'yes' if use_hint else 'no'} "
                  f"| {per_move} | {max(m.percent for m in moves):.1f} % | {inside}/{len(moves)} "
                  f"| {100 * float(track.untrusted.mean()):.0f} % | {first_flag} | {stops} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
