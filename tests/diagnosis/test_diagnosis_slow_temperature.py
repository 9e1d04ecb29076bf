"""A board temperature that swings slower than the record — the physical case — and one
that moves while the offset does not follow it.

A slow swing is nearly a line over the record: offset and drift take most of it on every
block, so its out-of-block gain is small (criterion.py). Named or not, nothing else may be
named for the residual it leaves (it used to be named `bias_random_walk` or `tilt`).
"""
from dataclasses import replace

import numpy as np
import pytest

from testing.diagnosis_cases import make_case, run_diagnosis

pytestmark = pytest.mark.slow


def test_a_swing_slower_than_the_record_is_named_or_nothing_is():
    named, reasons = [], []
    for seed in range(10):
        _, data = make_case(("temperature_offset",), seed, adjust=lambda t: replace(t, cycle_s=20.0))
        result = run_diagnosis(data)
        named.append(tuple(e.name for e in result.effects))
        reasons += [c.reason for c in result.candidates if c.name == "temperature_offset" and c.status == "accepted"]
    # over a 7.6 s record a 20 s swing may be nearly a line: then it cannot be told from
    # the drift, and naming nothing is the right answer; naming something else is not
    assert all(n in ((), ("temperature_offset",)) for n in named), named
    assert sum(n == ("temperature_offset",) for n in named) >= 6, named
    assert all("out-of-block" in r for r in reasons), reasons


@pytest.mark.parametrize("seed", range(4))
def test_a_temperature_that_moves_without_the_offset_following_is_not_named(seed):
    rng = np.random.default_rng(seed + 777)
    _, data = make_case((), seed)
    t = data.t_s - data.t_s[0]
    phase = rng.uniform(0.0, 1.0)
    reported_at = np.floor(t - phase) + phase  # once-a-second reports, as a board gives them
    data.temp_c = np.round(25.0 + rng.uniform(1.0, 4.0) * (1.0 - np.exp(-reported_at / rng.uniform(5.0, 30.0))), 2)
    assert [e.name for e in run_diagnosis(data).effects] == []
