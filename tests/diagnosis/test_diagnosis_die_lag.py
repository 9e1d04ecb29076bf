"""The temperature candidate with the die's thermal lag (signal_effects.TemperatureOffset,
model_compensation.die_temperature_c): the board's thermometer is not the accelerometer's
die, which follows it through its package (first order, τ within judgement.MAX_DIE_LAG_S).

On the own simulator a die lagging a 6 s swing by 2 s (sensor_effects.TemperatureTerm's
die_lag_s; TI's figure for a small package on a board) is what the candidate without a
lag fitted got wrong: on seeds 9300–9303 it fitted 36 %, 21 % and 26 % of the coefficient
(0.38 for 1.07 mg/°C, 0.13 for 0.61, −0.28 for −1.09) and named nothing on 9302 (a 0.5 Hz
line left in the residual). Tolerances by testing/diagnosis_cases.py's rule (the larger of 5 % and twice
the largest relative error seen, rounded up to 5 %) over seeds 9300–9307 with the lag
fitted: coefficient 21 % → 45 %, lag 18 % → 40 %.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis.judgement import MAX_DIE_LAG_S
from gateway.core.model_compensation import (
    ModelError,
    ModelTerm,
    SampleContext,
    SensorModel,
    check_terms,
    compensate,
    die_temperature_c,
    sample_path_refusal,
)
from testing.diagnosis_cases import make_case, run_diagnosis

DIE_LAG_S = 2.0


def test_the_die_temperature_is_the_first_order_lag_of_the_board_s():
    # oracle: a ramp of slope s from a settled start gives y = x − s·τ·(1 − e^(−t/τ))
    tau, slope = 3.0, 0.4
    t = np.arange(0.0, 20.0, 0.002)
    x = 25.0 + slope * t
    expected = x - slope * tau * (1.0 - np.exp(-t / tau))
    assert np.allclose(die_temperature_c(t, x, tau), expected, atol=1e-9)
    # a sine far from its start: amplitude 1/√(1 + (ωτ)²), phase −atan(ωτ), on uneven
    # times with a gap and a NaN (held as NaN)
    rng = np.random.default_rng(4)
    t = np.sort(rng.uniform(0.0, 60.0, 20000))
    t = t[(t < 30.0) | (t > 30.5)]
    w = 2.0 * math.pi / 6.0
    x = np.sin(w * t)
    x[100] = np.nan
    y = die_temperature_c(t, x, tau)
    late = t > 40.0
    gain, phase = 1.0 / math.hypot(1.0, w * tau), -math.atan(w * tau)
    assert np.allclose(y[late], gain * np.sin(w * t[late] + phase), atol=2e-3)
    assert np.isnan(y[100]) and np.isfinite(np.delete(y, 100)).all()
    assert np.array_equal(die_temperature_c(t, x, 0.0), x, equal_nan=True)


def test_the_model_file_applies_the_lag_it_was_fitted_with_and_checks_its_range():
    t = np.arange(0.0, 30.0, 0.002)
    board = 25.0 + 3.0 * np.sin(2.0 * math.pi * t / 8.0)
    die = die_temperature_c(t, board, 1.5)
    a = np.random.default_rng(2).normal(0.0, 1.0, t.size)
    params = {"offset_mps2_per_c": 0.01, "die_lag_s": 1.5, "reference_c": 25.0}
    model = SensorModel((ModelTerm("temperature_offset", params),))
    assert np.allclose(compensate(model, a + 0.01 * (die - 25.0), SampleContext(t, temp_c=board)), a)
    check_terms(model, "m.json")
    for bad in (-0.1, MAX_DIE_LAG_S + 1.0):
        with pytest.raises(ModelError, match="die_lag_s .* physical range"):
            check_terms(SensorModel((ModelTerm("temperature_offset", {**params, "die_lag_s": bad}),)), "m.json")
    # the daemon's compiled loop keeps no state for the lag: refused there, offline it applies
    assert "die lag" in sample_path_refusal(model, "m.json")
    assert sample_path_refusal(SensorModel((ModelTerm("temperature_offset", {**params, "die_lag_s": 0.0}),)),
                               "m.json") is None


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(9300, 9304))
def test_a_die_lagging_the_board_is_named_alone_with_its_lag(seed):
    (term,), data = make_case(("temperature_offset",), seed, adjust=lambda t: replace(t, die_lag_s=DIE_LAG_S))
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["temperature_offset"], [c.reason for c in result.candidates]
    (effect,) = result.effects
    assert effect.not_separable_from == []
    k = effect.params["offset_mg_per_c"][0]
    assert abs(k - term.offset_g_per_c * 1e3) <= 0.45 * abs(term.offset_g_per_c * 1e3), k
    lag = effect.params["die_lag_s"][0]
    assert abs(lag - DIE_LAG_S) <= 0.40 * DIE_LAG_S, lag
