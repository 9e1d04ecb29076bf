"""The diagnosis's noise model describes the sensor's noise, not the effects it looks for.

The noise model (an ARMA(1,1) of the residual at rest) whitens every comparison. Fitted on
the rests joined with their levels, a slow effect that moves the levels from one rest to
the next (a board temperature that swings) read as noise correlated over seconds — the AR
pole at its bound — and, whitened by that, the effect lost its evidence. Each rest is now
taken less its own mean (`Prepared.noise_series`).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from gateway.core.diagnosis.context import MIN_NOISE_REST, Prepared
from gateway.core.diagnosis.reading import fit_noise_model

PERIOD_S = 0.002  # 500 samples/s
NOISE_AR = 0.53  # the ADXL202's 50 Hz output filter at 500 Hz: e^(−2π·50·0.002)
SIGMA_MPS2 = 0.02


def rests_at_swinging_levels(seed: int, rest_samples: int = 400, move_samples: int = 300,
                             swing_mps2: float = 0.06):
    """A residual with AR(1) noise of NOISE_AR everywhere and, at rest, levels that follow
    one slow swing (±6 mg) over the record; between the rests, motion (not at rest)."""
    rng = np.random.default_rng(seed)
    n_rests = 8
    n = n_rests * rest_samples + (n_rests - 1) * move_samples
    noise = lfilter([1.0], [1.0, -NOISE_AR], SIGMA_MPS2 * rng.standard_normal(n))
    t = np.arange(n) * PERIOD_S
    level = swing_mps2 * np.sin(2 * np.pi * t / t[-1])
    rest = np.zeros(n, dtype=bool)
    for k in range(n_rests):
        a = k * (rest_samples + move_samples)
        rest[a:a + rest_samples] = True
    return level + noise, rest


def prepared(rest: np.ndarray, block: int = 1) -> Prepared:
    n = rest.size
    return Prepared(data=None, reading_mps2=np.zeros(n), rest=rest, drift_shape=np.zeros(n),
                    fit_mask=np.ones(n, dtype=bool), block=block)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rest_levels_that_swing_are_not_read_as_correlated_noise(seed):
    residual, rest = rests_at_swinging_levels(seed)
    joined = residual[rest] - residual[rest].mean()
    # what the noise model was fitted on before: the levels' steps read as correlation
    assert fit_noise_model(joined).ar > 0.9
    model = fit_noise_model(prepared(rest).noise_series(residual))
    assert model.lag1 == pytest.approx(NOISE_AR, abs=0.08)


def test_each_rest_is_taken_less_its_own_mean():
    residual, rest = rests_at_swinging_levels(3)
    series = prepared(rest).noise_series(residual)
    assert series.size == rest.sum()
    for k in range(8):
        piece = series[k * 400:(k + 1) * 400]
        assert abs(piece.mean()) < 1e-12


def test_a_coarse_comparison_takes_each_rest_less_its_mean_in_blocks():
    residual, rest = rests_at_swinging_levels(4)
    block = 8
    series = prepared(rest, block=block).noise_series(residual)
    # 8 rests of 400 samples: 50 blocks each where a rest starts on a block's edge, 49 where not
    assert 8 * 49 <= series.size <= 8 * 50
    assert abs(series[:400 // block].mean()) < 1e-12
    # block means of AR(1) noise are nearly white; a swing's steps would make them
    # strongly correlated
    assert fit_noise_model(series).lag1 < 0.5


def test_short_rests_are_left_out_and_too_few_points_fall_back_to_the_joined_rests():
    rng = np.random.default_rng(5)
    residual = 0.02 * rng.standard_normal(2000)
    rest = np.zeros(2000, dtype=bool)
    rest[0:MIN_NOISE_REST - 1] = True  # too short to take its mean from
    rest[100:400] = True
    series = prepared(rest).noise_series(residual)
    assert series.size == 300
    only_short = np.zeros(2000, dtype=bool)
    for a in range(0, 2000, 100):
        only_short[a:a + 10] = True
    # 200 points in all, but no rest long enough: the rests as they are, joined
    joined = prepared(only_short).noise_series(residual)
    assert np.array_equal(joined, residual[only_short])
