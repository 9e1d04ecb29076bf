"""The diagnosis measures an effect's distance gain on the estimate a user gets.

`adxlgw estimate` uses a recording's standstill_hint column by default (the machine's
"in position"); the diagnosis's distance estimates (gain.EstimatePlan) are the same
estimator fed the same hint. Measured without it, a compensation can gain against an
estimate no one runs and lose against the one that is run: on the Leiria robot's
horizontal moves a bias random walk gained 188 and 144 mm on the unhinted estimate and
loses 22 mm on each on the hinted one (docs/diagnosis.md §8).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from gateway.core.estimator import estimate_series
from testing.diagnosis_cases import estimator_settings, make_case, run_diagnosis


def _smoothed(data, hint):
    settings = replace(estimator_settings(), sensitivity_std_frac=0.0)  # as diagnose() runs it
    return estimate_series(data.t_s, data.acc_mps2, data.valid, method="smoothed", settings=settings,
                           lost_before=data.lost_before, standstill_hint=hint)


def test_the_distance_estimates_use_the_recordings_standstill_hint():
    _, data = make_case((), 3)
    # the machine's word: at rest where the reference stands
    data.standstill_hint = (np.abs(data.ref_vel_mps) < 1e-9).astype(float)
    result = run_diagnosis(data)
    before = result.distance["before"]
    hinted, unhinted = _smoothed(data, data.standstill_hint), _smoothed(data, None)
    assert np.array_equal(before.pos_m, hinted.pos_m)
    # the hint changes this estimate, so the equality above says the hint was used
    assert np.max(np.abs(hinted.pos_m - unhinted.pos_m)) > 1e-6
