"""The reported σ carries the sensitivity's uncertainty: a part whose sensitivity is off
within its calibration reads every acceleration (1 + s)·a, so a stop 0.3 m from the start
is off by s·0.3 m whatever the filter does — the σ must say so (never confidently wrong)."""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_rest, from_sensor_model
from gateway.core.evaluation import summarise_errors
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate

SENSITIVITY_ERROR = 0.009  # within the calibration's ±1 %


def _far_stops(method, settings, seed=3):
    nominal = SensorParams()
    part = replace(nominal, x=replace(nominal.x, sensitivity_error_frac=SENSITIVITY_ERROR))
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=4))), part, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    track = estimate_series(t, z, method=method, settings=settings)
    stops = summarise_errors(t, track.pos_m, run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2).stops
    far = [s for s in stops if run.ref_pos_m[s.index] > 0.2]
    assert len(far) >= 2
    return track, run, far


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_a_part_off_within_its_calibration_stays_inside_three_sigma(method):
    nominal = SensorParams()
    track, run, far = _far_stops(method, from_sensor_model(nominal))
    for stop in far:
        # the error is the sensitivity's, s·p (the noise is a tenth of it) ...
        assert abs(stop.error_m - SENSITIVITY_ERROR * run.ref_pos_m[stop.index]) < 0.3 * abs(stop.error_m)
        # ... and the band covers it
        assert abs(stop.error_m) <= 3 * track.pos_std_m[stop.index]
    # without the sensitivity's share the filter's σ alone claims a tenth of the error
    bare, _, far = _far_stops(method, from_sensor_model(nominal, sensitivity_std_frac=0.0))
    assert any(abs(s.error_m) > 3 * bare.pos_std_m[s.index] for s in far)


def test_the_share_is_the_sensitivity_times_the_position_and_velocity():
    nominal = SensorParams()
    with_share, _, far = _far_stops("realtime", from_sensor_model(nominal))
    bare, _, _ = _far_stops("realtime", from_sensor_model(nominal, sensitivity_std_frac=0.0))
    k = far[0].index
    expected = np.hypot(bare.pos_std_m[k], 0.005 * with_share.pos_m[k])
    assert with_share.pos_std_m[k] == pytest.approx(expected, rel=1e-9)
    moving = np.flatnonzero(np.abs(with_share.vel_mps) > 0.5)[0]
    assert with_share.vel_std_mps[moving] == pytest.approx(
        np.hypot(bare.vel_std_mps[moving], 0.005 * with_share.vel_mps[moving]), rel=1e-9)


def test_a_foreign_sensor_is_known_to_its_data_sheets_tolerance():
    rest = np.random.default_rng(5).normal(0.0, 0.02, 500)
    assert from_rest(rest, 0.01).sensitivity_std_frac == 0.015
    assert from_sensor_model().sensitivity_std_frac == 0.005
    with pytest.raises(ValueError, match="sensitivity_std_frac"):
        from_sensor_model(sensitivity_std_frac=-0.01)
