"""The hint's latency measured on the recording itself (gateway/core/hint_latency.py):
the same recording with its hint moved by ±50 ms gives the same aligned latency, a hint
with too few edges is not measured, and `estimate_series` says what it found."""
import numpy as np
import pytest

from gateway.core.estimator import estimate_series
from gateway.core.hint_latency import MIN_EDGES, aligned_hint, hint_latency
from testing.robot_like_cases import robot_case

# seeds the corpus benchmark never uses (it runs 0 … --seeds − 1, at most 5)
SEEDS = (41, 42)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_hint_moved_by_50_ms_is_found_where_the_accelerometer_puts_it(seed):
    t, z, _ref, resting, _settings = robot_case(seed, 0.0)
    period = float(np.median(np.diff(t)))
    truth = hint_latency(t, z, np.isfinite(z), resting.astype(float))
    assert truth.lag_s is not None and truth.edges >= MIN_EDGES
    # the sensor's own 50 Hz filter and the noise threshold put its edges a little after
    # the truth's, never before and never by a window
    assert 0.0 <= truth.lag_s <= 0.05
    for shift_s in (-0.05, 0.05):
        moved = aligned_hint(t, resting.astype(float), shift_s)  # the hint shift_s later
        found = hint_latency(t, z, np.isfinite(z), moved)
        assert found.lag_s is not None
        assert abs((found.lag_s + shift_s) - truth.lag_s) <= 2 * period


def test_a_hint_with_too_few_edges_is_not_measured_and_says_so():
    t, z, _ref, resting, _settings = robot_case(41, 0.0)
    hint = resting.astype(float)
    first_move = int(np.argmax(~resting))
    hint[first_move:] = 0.0  # one edge only
    found = hint_latency(t, z, np.isfinite(z), hint)
    assert found.lag_s is None
    assert "not measured" in found.describe(applied=False)


def test_estimate_series_reports_the_hints_latency():
    t, z, _ref, resting, settings = robot_case(41, 0.0)
    track = estimate_series(t, z, np.isfinite(z), method="realtime", settings=settings,
                            standstill_hint=resting.astype(float))
    assert any("the machine's hint" in note and "edges" in note for note in track.notes)
