"""The estimator on generated robot-like motion across rates, noise levels and offset steps.

    .venv/bin/python -m benchmarks.accuracy.robot_like_sweep [--seeds 5]

Issue 13's design ground besides the robot's design file: our simulator (the ADXL202
board model, its rate set by RSET and its noise by the density) driven through the
robot's path — moves of −0.634, +0.961, −0.327 m at 0.2 m/s (1 m/s² ramps: cruises of
3–5 s), a 0.5 s stop, a 0.1 s stop, rests of 3 s at both ends — at 100 and 500 samples/s
and white noise of 0.005–0.1 m/s² per sample at rest, with and without an offset step of
5 mg in the middle of the long move, with and without the rest hint (the truth's rests).
Settings from the sensor model (`from_sensor_model` with the same rate and noise), never
from the run. Per case, medians over the seeds: the worst move's error (per move between
two rests), how often the error at a rest end lies outside the filter's ±3σ, and the
share of the time flagged not trustworthy (flag 256).
"""
from __future__ import annotations

import argparse

import numpy as np

from benchmarks import harness
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import move_errors
from gateway.core.simulator import simulate
from testing.robot_like_cases import SPEED_MPS, G, robot_path, sensor_for


def one(rate_hz: float, noise: float, step_mg: float, seed: int, jerk_mps3: float = 0.0) -> dict:
    sensor = sensor_for(rate_hz, noise)
    run = simulate(robot_path(jerk_mps3), sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    if step_mg:
        long_cruise = np.flatnonzero(np.isclose(np.abs(run.ref_vel_mps), SPEED_MPS, rtol=0.0, atol=1e-12)
                                     & (run.ref_pos_m > -0.634 + 0.3))
        z[long_cruise[0]:] += step_mg * 1e-3 * G
    resting = (np.abs(run.ref_vel_mps) < 1e-12) & (run.ref_acc_mps2 == 0.0)
    settings = from_sensor_model(sensor)
    out = {}
    for name, method, hint in (("paper", "paper", None), ("realtime", "realtime", None),
                               ("realtime+hint", "realtime", resting.astype(float)),
                               ("smoothed", "smoothed", None)):
        track = estimate_series(t, z, method=method, settings=settings, standstill_hint=hint)
        moves = move_errors(track.pos_m, run.ref_pos_m, resting)
        ends = np.array([m.end for m in moves])
        outside = np.abs(track.pos_m[ends] - run.ref_pos_m[ends]) > 3 * track.pos_std_m[ends] + 1e-4
        out[name] = (max(m.percent for m in moves), float(outside.mean()), float(track.untrusted.mean()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--jerk-mps3", type=float, default=0.0,
                    help="drive the path jerk-limited at this jerk, m/s³ (e.g. 10: 0.1 s ramps); 0: steps (default)")
    args = ap.parse_args()
    harness.stamp("benchmarks.accuracy.robot_like_sweep")
    print("medians over the seeds: worst move (%) / rest ends outside ±3σ / time flagged (flag 256); "
          "paper has no σ")
    names = ("paper", "realtime", "realtime+hint", "smoothed")
    print("| rate | noise at rest | offset step | " + " | ".join(names) + " |")
    print("|" + " --- |" * (3 + len(names)))
    for rate in (100.0, 500.0):
        for noise in (0.005, 0.02, 0.1):
            for step in (0.0, 5.0):
                res = [one(rate, noise, step, seed, args.jerk_mps3) for seed in range(args.seeds)]
                cells = []
                for n in names:
                    worst = np.median([r[n][0] for r in res])
                    outside = np.median([r[n][1] for r in res])
                    flagged = np.median([r[n][2] for r in res])
                    cells.append(f"{worst:.1f} %" if n == "paper" else
                                 f"{worst:.1f} % / {100 * outside:.0f} % / {100 * flagged:.0f} %")
                print(f"| {rate:g} Hz | {noise:g} m/s² | {step:g} mg | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
