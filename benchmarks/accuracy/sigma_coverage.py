"""Is the estimator's σ at the stops honest for a part whose sensitivity is off within its
calibration? On the simulator (the design data), the paper's 10 strokes:

    .venv/bin/python -m benchmarks.accuracy.sigma_coverage [--seeds 10] [--dcm-reading edge]

Per seed a part whose X sensitivity is off by s, drawn uniformly within the calibration's
±1 % (seeded), and a nominal part (s = 0). The filter's settings from the sensor model, once
with the sensitivity's uncertainty in the reported σ (the default, `sensitivity_std_frac`)
and once without it (0): the share of the stop errors inside ±3σ, the largest |error|/3σ,
and the median σ at the stops (what the wider band costs). `--dcm-reading edge`: the
simulated board's modulator reads where each duty cycle ends (SensorParams.dcm_reading),
not over the period; the filter is never told which (its σ carries the difference since
2026-11-27, `EstimatorSettings.duty_cycle_reading_unknown`).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks import harness
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import summarise_errors
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import CALIBRATED_SENSITIVITY_TOLERANCE_FRAC, DCM_READINGS, SensorParams
from gateway.core.simulator import simulate

ROOT = Path(__file__).resolve().parents[2]

CALIBRATION_TOLERANCE_FRAC = CALIBRATED_SENSITIVITY_TOLERANCE_FRAC
METHODS = ("realtime", "smoothed")


# the reported σ's shares: (the sensitivity's, the duty-cycle reading instant's)
SHARES = ((False, False), (True, False), (True, True))


def stop_ratios(seed: int, sensitivity_error_frac: float, dcm_reading: str = "mean") -> dict[tuple, tuple[list, list]]:
    """Per (method, σ's shares): the stops' |error|/3σ and σ (m)."""
    nominal = SensorParams()
    sensor = replace(nominal, x=replace(nominal.x, sensitivity_error_frac=sensitivity_error_frac),
                     dcm_reading=dcm_reading)
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=10))), sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    out = {}
    for with_scale, with_reading in SHARES:
        # the filter is told the part's model, never its error nor its reading instant
        settings = from_sensor_model(nominal, duty_cycle_reading_unknown=with_reading,
                                     **({} if with_scale else {"sensitivity_std_frac": 0.0}))
        for method in METHODS:
            track = estimate_series(t, z, np.ones(t.size, dtype=bool), method=method, settings=settings)
            stops = summarise_errors(t, track.pos_m, run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2).stops
            sigma = [float(track.pos_std_m[s.index]) for s in stops]
            out[(method, with_scale, with_reading)] = ([abs(s.error_m) / (3 * sd) if sd > 0 else np.inf
                                          for s, sd in zip(stops, sigma, strict=False)], sigma)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--dcm-reading", choices=DCM_READINGS, default="mean",
                    help="where the simulated modulator reads the signal (default: the period's mean)")
    args = ap.parse_args()
    harness.stamp("benchmarks.accuracy.sigma_coverage")
    rng = np.random.default_rng(20261126)
    errors = rng.uniform(-CALIBRATION_TOLERANCE_FRAC, CALIBRATION_TOLERANCE_FRAC, args.seeds)
    print(f"parts' sensitivity errors: {', '.join(f'{100 * e:+.2f} %' for e in errors)}")
    print("| part | method | σ carries the sensitivity | σ carries the reading instant | stops inside ±3σ "
          "| largest error / 3σ | median σ at the stops |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, parts in (("within ±1 %", errors), ("nominal (s = 0)", np.zeros(args.seeds))):
        pooled: dict[tuple, tuple[list, list]] = {}
        for seed, s in enumerate(parts):
            for key, (ratios, sigma) in stop_ratios(seed, float(s), args.dcm_reading).items():
                pooled.setdefault(key, ([], []))
                pooled[key][0].extend(ratios)
                pooled[key][1].extend(sigma)
        for (method, with_scale, with_reading), (ratios, sigma) in sorted(pooled.items()):
            r = np.asarray(ratios)
            print(f"| {label} | {method} | {'yes' if with_scale else 'no'} | {'yes' if with_reading else 'no'} "
                  f"| {100 * np.mean(r <= 1):.1f} % of {r.size} "
                  f"| {r.max():.2f} | {1e3 * float(np.median(sigma)):.3f} mm |")


if __name__ == "__main__":
    main()
