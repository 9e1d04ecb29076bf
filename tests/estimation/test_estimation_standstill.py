"""The standstill detector: a cruise is not a standstill, a slow ramp is not one, a stop is."""
import numpy as np
import pytest

from gateway.core import estimator_kernel as K
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.motion_profiles import PiecewiseConstantAcceleration, Segment, single_move
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate


def _run(profile, seed):
    sensor = SensorParams()
    run = simulate(profile, sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    return sensor, run, t, z


def _window_variance(z, w):
    """Trailing-window sample variance, numpy (independent of the kernel's ring buffer)."""
    out = np.full(z.size, np.inf)
    for k in range(w - 1, z.size):
        out[k] = np.var(z[k - w + 1:k + 1], ddof=1)
    return out


@pytest.mark.parametrize("seed", [110, 111])
def test_a_two_second_cruise_at_one_metre_per_second_is_not_a_standstill(seed):
    profile = single_move(distance_m=2.1, max_speed_mps=1.0, max_acc_mps2=10.0, rest_start_s=1.0, rest_end_s=1.0)
    sensor, run, t, z = _run(profile, seed)
    # the filter's own σ: this part's sensitivity is exact, and the share a calibrated
    # one's would add (0.5 % of 2.1 m) is tested in test_estimation_sigma_carries_the_sensitivity.py
    settings = from_sensor_model(sensor, sensitivity_std_frac=0.0)
    cruise = (run.ref_vel_mps == 1.0) & (run.ref_acc_mps2 == 0.0)
    assert t[cruise][-1] - t[cruise][0] > 1.9
    # the pitfall is real: the acceleration alone looks like rest during the cruise
    quiet = _window_variance(z, settings.window_samples) <= settings.window_variance_threshold_mps2_sq
    settled = cruise & (t > t[cruise][0] + 0.2)
    assert quiet[settled].mean() > 0.9
    track = estimate_series(t, z, method="realtime", settings=settings)
    assert not track.standstill[cruise].any()
    end = np.flatnonzero(cruise)[-1]
    assert abs(track.vel_mps[end] - 1.0) < 4 * track.vel_std_mps[end] < 0.02
    # and the stop after it is found, with the 2.1 m move measured to the millimetre
    assert track.standstill[-10:].all()
    assert abs(track.pos_m[-1] - 2.1) < 4 * track.pos_std_m[-1] < 0.01


def test_a_slow_steady_acceleration_is_not_a_standstill():
    """0.05 m/s² passes the variance test; the mean test (bias consistency) catches it."""
    profile = PiecewiseConstantAcceleration([Segment(1.0, 0.0), Segment(2.0, 0.05), Segment(2.0, -0.05),
                                             Segment(1.0, 0.0)])
    sensor, run, t, z = _run(profile, 112)
    settings = from_sensor_model(sensor)
    ramp = (t > 1.15) & (t < 5.0)
    quiet = _window_variance(z, settings.window_samples) <= settings.window_variance_threshold_mps2_sq
    assert quiet[ramp].mean() > 0.9  # the variance test alone would miss the motion
    track = estimate_series(t, z, method="realtime", settings=settings)
    assert not track.standstill[ramp].any()
    assert abs(track.pos_m[-1] - 0.2) < 4 * track.pos_std_m[-1] < 0.02
    # the gentle start was found late: the filter went back to its onset (rollback)
    assert np.any(track.flags & K.F_ROLLBACK)


def test_stops_are_found_within_a_window_of_their_start():
    profile = single_move(distance_m=0.3, rest_start_s=1.0, rest_end_s=1.0)
    sensor, run, t, z = _run(profile, 113)
    settings = from_sensor_model(sensor)
    track = estimate_series(t, z, method="realtime", settings=settings)
    end_of_motion = t[np.flatnonzero(run.ref_vel_mps != 0.0)[-1]] + 0.02  # + the sensor filter's settling
    first_still = t[np.flatnonzero(track.standstill & (t > end_of_motion))[0]]
    assert first_still - end_of_motion <= settings.standstill_window_s + 0.02
    moving = (run.ref_vel_mps != 0.0) | (run.ref_acc_mps2 != 0.0)
    assert not track.standstill[moving].any()
