"""The simulated accelerometer must integrate to the truth: the estimators' goals are in µm–mm.

The simulator's sample is the period mean of the continuously filtered acceleration
(gateway/core/simulator.py: period_mean_lowpass). Checked against a fine-grid numerical
oracle and by integrating a noise-free run.
"""
import numpy as np
import pytest

from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import period_mean_lowpass


def _fine_grid_oracle(profile, n, period_s, bandwidth_hz, sub=400):
    """Euler-free oracle: exact one-pole steps on a grid `sub` times finer, then trapezoid means."""
    tau = 1.0 / (2 * np.pi * bandwidth_hz)
    h = period_s / sub
    t = np.arange(n * sub + 1) * h
    _, _, u = profile.evaluate(t + h / 2)  # u constant on each fine cell (edges fall between cells)
    a = np.exp(-h / tau)
    y = np.empty(t.size)
    y[0] = profile.evaluate(0.0)[2]
    for_cell = u[:-1] * (1 - a)
    from scipy.signal import lfilter

    y[1:], _ = lfilter([1.0], [1.0, -a], for_cell, zi=[a * y[0]])
    cell_mean = (y[1:] + y[:-1]) / 2
    return cell_mean.reshape(n, sub).mean(axis=1)


def test_period_mean_matches_a_fine_grid_oracle():
    sensor = SensorParams()
    profile = reciprocating_strokes(StrokeSettings(strokes=2))
    n = int(profile.duration_s / sensor.t2_s)
    exact = period_mean_lowpass(profile, n, sensor.t2_s, sensor.bandwidth_hz)
    oracle = _fine_grid_oracle(profile, n, sensor.t2_s, sensor.bandwidth_hz)
    # the oracle's own error: an edge inside a fine cell is off by ≤ h/2 → ≤ a·h/(2·Ts) per sample
    assert np.max(np.abs(exact - oracle)) < 10.0 / 400
    assert np.sum(exact - oracle) * sensor.t2_s == pytest.approx(0.0, abs=1e-4)


def test_noise_free_samples_integrate_to_the_reference_motion():
    sensor = SensorParams()
    profile = reciprocating_strokes(StrokeSettings(strokes=4))
    dt = sensor.t2_s
    n = int(profile.duration_s / dt)
    acc = period_mean_lowpass(profile, n, dt, sensor.bandwidth_hz)
    t = np.arange(n + 1) * dt
    vel = np.concatenate([[0.0], np.cumsum(acc * dt)])
    pos = np.concatenate([[0.0], np.cumsum(vel[:-1] * dt + 0.5 * acc * dt * dt)])
    ref_pos, ref_vel, _ = profile.evaluate(t)
    # velocity is exact at every period edge (the filter's lag cancels once settled)
    settled = np.zeros(t.size, bool)
    for start, end in profile.standstill_intervals():
        settled |= (t > start + 0.05) & (t < end)
    assert np.max(np.abs(vel - ref_vel)[settled]) < 1e-7  # e^(−0.05 s/τ) of the lag is left
    # position: within a period the mean hides the shape: O(Δa·Ts²) per step, sub-µm
    assert np.max(np.abs(pos - ref_pos)[settled]) < 1e-6
