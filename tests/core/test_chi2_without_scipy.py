"""The daemon's χ² numbers come from gateway/core/chi2.py (scipy is not in the daemon's
install, and its import cost the start half a second): the values scipy.stats gives, to
1e-12 relative — a variance threshold that close moves no decision of a recorded test."""
import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from gateway.core.drift_fit import ljung_box
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.sensor_model import SensorParams


@pytest.mark.parametrize("window_s", [0.02, 0.1, 0.5])
@pytest.mark.parametrize("false_motion_prob", [1e-2, 1e-4, 1e-7])
def test_the_standstill_threshold_is_scipy_stats_chi2_ppf(window_s, false_motion_prob):
    base = from_sensor_model(SensorParams())
    s = dataclasses.replace(base, standstill_false_motion_prob=false_motion_prob, standstill_window_s=window_s)
    nu = s.window_dof
    expected = s.sample_noise_std_mps2**2 * float(chi2.ppf(1.0 - false_motion_prob, nu)) / nu
    assert s.window_variance_threshold_mps2_sq == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_the_ljung_box_p_value_is_scipy_stats_chi2_sf(seed):
    x = np.random.default_rng(seed).normal(size=500) + 0.05 * seed * np.arange(500) / 500
    lb = ljung_box(x)
    assert lb.p_value == pytest.approx(float(chi2.sf(lb.statistic, lb.lags)), rel=1e-10, abs=1e-300)
