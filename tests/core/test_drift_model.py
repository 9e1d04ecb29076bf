import numpy as np
import pytest

from gateway.core.drift_model import DriftModel, drift_g, drift_recursive_g


def test_closed_form_meets_the_papers_initial_conditions():
    m = DriftModel(c1_g=0.004, c2_g=0.001, time_constant_s=100.0)
    assert drift_g(0.0, m) == pytest.approx(0.001)
    # ε'(0) = C1/T by finite difference
    h = 1e-4
    assert (drift_g(h, m) - drift_g(0.0, m)) / h == pytest.approx(0.004 / 100.0, rel=1e-5)
    assert drift_g(1e6, m) == pytest.approx(0.005)


def test_exact_recursion_equals_closed_form_with_varying_periods():
    rng = np.random.default_rng(0)
    periods = rng.uniform(0.0015, 0.0025, 20000)
    m = DriftModel(0.003, -0.001, 7.0)
    t = np.concatenate([[0.0], np.cumsum(periods)[:-1]])
    np.testing.assert_allclose(drift_recursive_g(periods, m), drift_g(t, m), atol=1e-15, rtol=1e-12)


def test_corrected_backward_euler_settles_at_c1_plus_c2_and_the_misprint_does_not():
    m = DriftModel(0.003, 0.001, 1.0)
    periods = np.full(20000, 0.002)
    assert drift_recursive_g(periods, m, exact=False)[-1] == pytest.approx(0.004, rel=1e-9)
    # the paper's printed eq. 2 uses T/(T+Ts) on the constant term: it settles elsewhere
    T, ts, eps = 1.0, 0.002, 0.001
    for _ in range(20000):
        eps = T / (T + ts) * eps + T / (T + ts) * 0.004
    assert abs(eps - 0.004) > 1.0


def test_time_constant_must_be_positive():
    with pytest.raises(ValueError):
        DriftModel(time_constant_s=0.0)
