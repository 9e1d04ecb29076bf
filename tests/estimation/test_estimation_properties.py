"""Property: whatever the sequence of samples (hints and restarts included), the covariance
stays symmetric and positive (semi)definite and the outputs stay finite.

Semidefinite, not definite, by design: at standstill the velocity is exactly zero (its
row of P is 0), and at the reference point or after a tare the position is exact. The
property checks symmetry to the bit, no eigenvalue below −1e-12 of the largest, and
strictly positive variance of every state the model says is uncertain.
"""
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.core import estimator_kernel as K
from gateway.core.estimator import RealtimeEstimator
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.sensor_model import SensorParams

SETTINGS = from_sensor_model(SensorParams())
PERIOD = SETTINGS.sample_period_s

segment = st.one_of(
    st.tuples(st.just("still"), st.integers(1, 120), st.floats(-0.5, 0.5)),  # bias in m/s²
    st.tuples(st.just("move"), st.integers(1, 120), st.floats(-20.0, 20.0)),  # acceleration
    st.tuples(st.just("invalid"), st.integers(1, 10), st.sampled_from([None, math.nan, math.inf, -math.inf])),
    st.tuples(st.just("gap"), st.integers(1, 500), st.just(0.0)),
    st.tuples(st.just("time_back"), st.just(1), st.just(0.0)),
    st.tuples(st.just("tare"), st.just(0), st.just(0.0)),
    st.tuples(st.just("reestimate"), st.just(0), st.just(0.0)),
    st.tuples(st.just("hint"), st.just(0), st.sampled_from([1.0, 0.0, None])),  # the machine's word
    st.tuples(st.just("restart"), st.just(0), st.just(0.0)),  # velocity unknown from here
)


def _check(est: RealtimeEstimator, e, prev) -> None:
    P = est.covariance
    assert np.array_equal(P, P.T)
    assert np.all(np.isfinite(P))
    eig = np.linalg.eigvalsh(P)
    assert eig.min() >= -1e-12 * max(1.0, eig.max())
    assert np.all(np.diag(P) >= 0.0)
    clock_ok = not (e.flags & K.F_TIME_ERROR) and prev is not None and not (prev.flags & K.F_TIME_ERROR)
    if e.initialised and not e.standstill and clock_ok and prev.initialised and not prev.standstill:
        # in motion the velocity is uncertain (on the first motion sample it is still the
        # rest's exact 0: the motion starts with that sample's period; and without time
        # passing nothing is propagated)
        assert P[1, 1] > 0.0
    assert P[2, 2] > 0.0  # the bias is never known exactly (random walk, prior)
    for value in (e.pos_m, e.vel_mps, e.acc_mps2, e.bias_mps2, e.pos_std_m, e.vel_std_mps, e.innovation_mps2,
                  e.nis, e.zupt_velocity_error_mps, e.zupt_nis):
        assert math.isfinite(value)


@settings(max_examples=60, deadline=None)
@given(st.lists(segment, min_size=1, max_size=25), st.integers(0, 2**31 - 1))
def test_covariance_stays_symmetric_psd_and_outputs_finite(segments, seed):
    rng = np.random.default_rng(seed)
    est = RealtimeEstimator(SETTINGS)
    t = 0.0
    prev = None
    noise = SETTINGS.sample_noise_std_mps2
    for kind, count, value in [("still", 60, 0.1)] + segments:
        if kind == "tare":
            est.tare()
            continue
        if kind == "reestimate":
            est.request_bias_reestimate()
            continue
        if kind == "hint":
            est.set_hint(value)
            continue
        if kind == "restart":
            est.restart()
            prev = None
            continue
        for _ in range(count):
            lost = 0
            if kind == "gap":
                lost = count
                t += PERIOD * count
            if kind == "time_back":
                t -= PERIOD
            else:
                t += PERIOD
            if kind == "invalid":
                acc = value
            elif kind == "move":
                acc = value + rng.normal(0, noise)
            else:
                acc = 0.1 + (value if kind == "still" else 0.0) + rng.normal(0, noise)
            e = est.step(t, acc, lost)
            _check(est, e, prev)
            prev = e
            if kind == "gap":
                break
