"""Lost samples at every phase of a stroke: is the estimate ever confidently wrong afterwards?

    PYTHONPATH=. .venv/bin/python benchmarks/gap_phase.py [--positions 140] [--seed 0]

The paper experiment (10 strokes, data-sheet noise, one seed); a gap of G samples (2 ms
each) is cut at P positions spread evenly over one stroke period (the third stroke and
its dwell), offline, as a serial glitch would leave it. Per gap length, over the
positions: how often the error at the last stop is above 5 mm, how often that happens
with the "not trustworthy" flag (256) clear at the end — confidently wrong, what issue 13
forbids — and the share of samples after the gap whose error lies outside the filter's
±3σ.
"""
from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.machine_info import machine  # noqa: E402
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s  # noqa: E402
from gateway.core.estimator import estimate_series  # noqa: E402
from gateway.core.estimator_settings import from_sensor_model  # noqa: E402
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes  # noqa: E402
from gateway.core.sensor_model import SensorParams  # noqa: E402
from gateway.core.simulator import simulate  # noqa: E402

GAPS = (5, 10, 25)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--positions", type=int, default=140)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sensor = SensorParams()
    s = StrokeSettings(strokes=10)
    run = simulate(reciprocating_strokes(s), sensor, seed=args.seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    settings = from_sensor_model(sensor)
    moving = np.flatnonzero(run.ref_vel_mps != 0.0)
    starts = moving[np.flatnonzero(np.diff(np.concatenate([[-2], moving])) > 1)]  # first sample of each stroke
    period = slice(starts[2], starts[3])  # the third stroke and its dwell
    positions = np.linspace(period.start, period.stop - 1, args.positions).astype(int)
    print(f"command: PYTHONPATH=. .venv/bin/python benchmarks/gap_phase.py --positions {args.positions} "
          f"--seed {args.seed}")
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    print("| gap | positions | error at the last stop > 5 mm | of those, flag 256 clear at the end "
          "(confidently wrong) | worst error at the last stop | samples after the gap outside ±3σ |")
    print("| --- | --- | --- | --- | --- | --- |")
    for g in GAPS:
        big = wrong = 0
        worst = 0.0
        outside = []
        for i in positions:
            keep = np.ones(t.size, bool)
            keep[i:i + g] = False
            lost = np.zeros(keep.sum(), np.int64)
            lost[i] = g
            track = estimate_series(t[keep], z[keep], method="realtime", settings=settings, lost_before=lost)
            err = np.abs(track.pos_m - run.ref_pos_m[keep])
            final = float(err[-1])
            worst = max(worst, final)
            if final > 5e-3:
                big += 1
                wrong += int(not track.untrusted[-1])
            after = slice(i, None)
            outside.append(float(np.mean(err[after] > 3 * track.pos_std_m[after] + 1e-4)))
        print(f"| {g} samples ({2 * g} ms) | {positions.size} | {big} | {wrong} | {worst * 1e3:.1f} mm "
              f"| {100 * np.mean(outside):.2f} % (worst position {100 * np.max(outside):.1f} %) |")


if __name__ == "__main__":
    main()
