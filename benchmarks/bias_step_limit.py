"""How large a bias change between stops the realtime estimator survives.

    PYTHONPATH=. .venv/bin/python benchmarks/bias_step_limit.py [--seeds 5]

The paper's experiment (10 strokes of 0.3 m, data-sheet noise, seeds 0…N−1); in the
middle of the run, during a cruise, the sensor's offset steps by Δ (mg) and stays — what
a tilt change along a rail of 0.06° per mg, a temperature step or a knock on the mount
does. The standstill detector's mean test compares each stop's mean with the filter's
bias, so a step larger than its tolerance (a few mg: 5 σ of a 0.1 s window's mean plus
the bias uncertainty, which the data sheet's tiny random walk keeps small) is never
accepted as a stop again: no more zero-velocity updates, the position drifts.

Prints, per Δ: the median final position error and the share of the true rest time
after the step that the filter called standstill.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s  # noqa: E402
from gateway.core.estimator import estimate_series  # noqa: E402
from gateway.core.estimator_settings import from_sensor_model  # noqa: E402
from gateway.core.motion_profiles import StrokeSettings  # noqa: E402
from gateway.core.scenarios import ScenarioSettings, build_profile  # noqa: E402
from gateway.core.sensor_model import SensorParams  # noqa: E402
from gateway.core.simulator import simulate  # noqa: E402
from gateway.core.units import STANDARD_GRAVITY_MPS2  # noqa: E402

STEPS_MG = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 10.0)


def one_seed(seed: int) -> list[tuple[float, float, float]]:
    sensor = SensorParams()
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=10))), sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    settings = from_sensor_model(sensor)
    cruising = np.flatnonzero(np.abs(run.ref_vel_mps) > 0.5)
    k = cruising[cruising.size // 2]  # mid-cruise of a middle stroke
    at_rest_after = (np.arange(t.size) > k) & (run.ref_vel_mps == 0.0) & (run.ref_acc_mps2 == 0.0)
    rows = []
    for step_mg in STEPS_MG:
        stepped = z.copy()
        stepped[k:] += step_mg * 1e-3 * STANDARD_GRAVITY_MPS2
        track = estimate_series(t, stepped, method="realtime", settings=settings)
        rows.append((step_mg, abs(track.pos_m[-1] - run.ref_pos_m[-1]), track.standstill[at_rest_after].mean()))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    results = [one_seed(seed) for seed in range(args.seeds)]
    print(f"command: PYTHONPATH=. .venv/bin/python benchmarks/bias_step_limit.py --seeds {args.seeds}")
    print(f"{'offset step':>12} {'median |final error|':>22} {'rest seen as standstill':>25}")
    for i, step_mg in enumerate(STEPS_MG):
        errors = [r[i][1] for r in results]
        seen = [r[i][2] for r in results]
        print(f"{step_mg:9.1f} mg {np.median(errors) * 1e3:19.1f} mm {np.median(seen) * 100:23.0f} %")


if __name__ == "__main__":
    main()
