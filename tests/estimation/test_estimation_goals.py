"""The issue's goals on the paper's experiment, on seeds the benchmark and tuning never used.

Goals (benchmarks/accuracy/estimation_benchmark.py measures them on seeds 0–19): realtime ≤ 1 mm
median at the 10th stop and within 2× of the noise floor (the same filter told the true
bias and drift); smoothed better still (in motion: at a stop both are on the noise floor); the paper's
filter drifts (tens of mm).
Six seeds make a noisy median, so the margins here are the goals themselves, not
tighter: a failure means the goal is missed on these seeds.
"""
import numpy as np
import pytest

from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.drift_model import drift_g
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import summarise_errors
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2

SEEDS = range(100, 106)


@pytest.fixture(scope="module")
def results():
    sensor = SensorParams()
    settings = from_sensor_model(sensor)
    profile = reciprocating_strokes(StrokeSettings(strokes=10))
    out = {m: {"tenth": [], "rms": [], "vel_rms": [], "moving_max": []}
           for m in ("raw", "paper", "realtime", "smoothed", "floor")}
    for seed in SEEDS:
        run = simulate(profile, sensor, seed=seed)
        t = sample_times_s(run.t2, run.tick_hz)
        z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
        true_bias = (sensor.x.zero_g_offset_g + drift_g(t, sensor.x.drift)) * STANDARD_GRAVITY_MPS2
        for name, method, extra in (("raw", "raw", {}), ("paper", "paper", {}), ("realtime", "realtime", {}),
                                    ("smoothed", "smoothed", {}),
                                    ("floor", "realtime", {"known_bias_mps2": true_bias})):
            track = estimate_series(t, z, method=method, settings=settings, **extra)
            s = summarise_errors(t, track.pos_m, run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2, track.vel_mps)
            assert len(s.stops) == 10
            out[name]["tenth"].append(abs(s.stops[-1].error_m))
            out[name]["rms"].append(s.rms_m)
            out[name]["vel_rms"].append(s.vel_rms_mps)
            out[name]["moving_max"].append(s.moving_max_m)
    return {m: {k: float(np.median(v)) for k, v in d.items()} for m, d in out.items()}


def test_realtime_is_within_a_millimetre_at_the_tenth_stop(results):
    assert results["realtime"]["tenth"] <= 1e-3


def test_realtime_is_within_twice_the_noise_floor(results):
    assert results["realtime"]["tenth"] <= 2 * results["floor"]["tenth"]


def test_smoothed_tracks_better_than_realtime(results):
    """At the stops both sit on the noise floor (the noise integrated during a stroke is
    not observable afterwards); in motion the backward pass spreads the stop's velocity
    error over the stroke: velocity and in-motion position errors drop."""
    assert results["smoothed"]["vel_rms"] < 0.8 * results["realtime"]["vel_rms"]
    assert results["smoothed"]["moving_max"] < results["realtime"]["moving_max"]
    assert results["smoothed"]["tenth"] <= 1e-3


def test_the_papers_filter_and_raw_integration_drift(results):
    assert results["paper"]["tenth"] > 10e-3
    assert results["raw"]["tenth"] > 10 * results["paper"]["tenth"]
