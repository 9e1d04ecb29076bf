"""Re-timing bursty arrival times onto the sensor's regular clock (gateway/core/retiming.py)."""
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.optimize import linprog

from gateway.core.retiming import RetimingError, RetimingSettings, fit_floor_line, on_sample_clock, retime, timing_error
from testing.arrival_times import TRANSFER_S, bursty_arrivals

# between the last arrival on the floor before a gap and the first after it, arrivals cannot
# tell where the sample was lost: a found gap may sit this many rows off
GAP_PLACE_ROWS = 3


def assert_gaps_found(r, lost_true, rows=GAP_PLACE_ROWS):
    """Same gaps, same counts, each within `rows` rows; returns the rows next to a gap."""
    truth = [(int(i), int(lost_true[i])) for i in np.flatnonzero(lost_true)]
    assert [m for _, m in r.gaps] == [m for _, m in truth]
    near = np.zeros(lost_true.size, dtype=bool)
    for (found, _), (true, _) in zip(r.gaps, truth, strict=False):
        assert abs(found - true) <= rows
        near[min(found, true) - rows:max(found, true) + rows] = True
    return near


def test_floor_line_is_the_linear_programme_it_stands_for():
    # oracle: scipy's LP solver on max Σ(t0 + T·k) subject to t0 + T·k_i ≤ a_i
    rng = np.random.default_rng(7)
    for _ in range(5):
        k = np.sort(rng.choice(4000, size=500, replace=False)).astype(float)
        a = 3.0 + 0.0123 * k + rng.exponential(0.004, size=k.size)
        res = linprog(c=[-k.size, -k.sum()], A_ub=np.column_stack([np.ones_like(k), k]), b_ub=a,
                      bounds=[(None, None), (None, None)], method="highs")
        t0, T = fit_floor_line(k, a)
        assert res.status == 0
        assert pytest.approx(res.x[1], rel=1e-9) == T
        assert t0 == pytest.approx(res.x[0], abs=1e-9)
        assert np.all(t0 + T * k <= a + 1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_bursty_arrivals_give_back_the_sample_times_and_the_lost_samples(seed):
    tau, arrival, k_true, lost_true = bursty_arrivals(seed)
    r = retime(arrival)
    assert r.period_s == pytest.approx(0.010, rel=2e-5)
    near = assert_gaps_found(r, lost_true)
    np.testing.assert_array_equal(r.sample_index[~near], k_true[~near])
    # within 1 ms (the floor is reached to within the 0.3 ms jitter plus where the polls fall);
    # next to a gap a row may be placed on the wrong side of it: off by the gap's length
    err = r.t_s - tau - timing_error(r.t_s, tau).offset_s
    assert np.abs(err[~near]).max() < 1e-3
    assert np.abs(err[near]).max() < lost_true.max() * 0.010 + 1e-3
    assert timing_error(r.t_s, tau).interval_rms_s < 0.5e-3
    assert np.all(r.t_s <= arrival + 1e-12)  # no sample after its own arrival
    assert r.late[0].start == 0 and 300 <= r.late[0].stop <= 420
    assert r.late[0].arrival_interval_s == pytest.approx(TRANSFER_S, rel=0.05)
    assert any(ep.start <= 1800 < ep.stop for ep in r.late[1:])  # the stall
    assert r.bursts > 0 and r.burst_interval_s == pytest.approx(TRANSFER_S, rel=0.1)


@pytest.mark.parametrize("mismatch_ppm", [-3000.0, 800.0])
def test_clock_rate_mismatch_is_measured_not_assumed(mismatch_ppm):
    period = 0.0115 * (1 + mismatch_ppm * 1e-6)
    tau, arrival, _, lost_true = bursty_arrivals(11, n=2000, period_s=period, lost=((900, 2),), stall=(1200, 0.1))
    r = retime(arrival)
    assert (r.period_s / period - 1) * 1e6 == pytest.approx(0.0, abs=50.0)
    near = assert_gaps_found(r, lost_true)
    err = r.t_s - tau - timing_error(r.t_s, tau).offset_s
    assert np.abs(err[~near]).max() < 1e-3


def test_symmetric_jitter_without_bursts_finds_no_gaps():
    rng = np.random.default_rng(3)
    tau = 0.002 * np.arange(5000)  # 500 samples/s
    arrival = np.maximum.accumulate(tau + rng.normal(0.0, 0.2e-3, size=tau.size))
    r = retime(arrival)
    assert r.gaps == [] and not r.late
    assert timing_error(r.t_s, tau).max_s < 0.3e-3  # the line through the lowest arrivals


def test_a_backlog_longer_than_the_rest_of_the_file_does_not_set_the_period():
    tau, arrival, _, lost_true = bursty_arrivals(8, n=1500, lost=((1350, 2),), backlog=900, stall=(1280, 0.05))
    # 9 s of samples flushed 2.5 ms apart for 3 s, then 3 s of steady arrivals: the arrivals
    # alone say "400 samples/s, falling behind at the end"; the data sheet's 100 Hz, 3 % off, decides
    guess = retime(arrival)
    assert guess.period_s == pytest.approx(TRANSFER_S, rel=1e-3)
    assert guess.falling_behind is not None  # and it says it cannot tell
    r = retime(arrival, RetimingSettings(nominal_rate_hz=97.0))
    assert r.falling_behind is None
    assert r.late[0].start == 0 and r.late[0].stop > 1150
    assert r.period_s == pytest.approx(0.010, rel=1e-3)  # 3 s of steady arrivals: to ~0.1 %
    assert_gaps_found(r, lost_true)


def test_a_gap_inside_the_start_up_backlog_is_unseen_and_said_so():
    tau, arrival, _, lost_true = bursty_arrivals(5, lost=((100, 2), (1500, 1)))
    r = retime(arrival)
    assert len(r.gaps) == 1 and abs(r.gaps[0][0] - 1500) <= GAP_PLACE_ROWS and r.gaps[0][1] == 1
    assert r.blind_rows > 100  # the report names the rows where a gap cannot be seen


@pytest.mark.parametrize(
    "arrival, message",
    [
        (np.arange(5.0), "5 arrival times; re-timing needs at least 20"),
        (np.r_[np.arange(10.0), 3.0, np.arange(11.0, 30.0)], "row 10: arrival time goes backwards"),
        (np.r_[np.arange(10.0), np.nan, np.arange(11.0, 30.0)], "row 10: arrival time is not finite"),
        (np.zeros(30), "all arrival times are equal"),
    ],
)
def test_arrival_times_that_cannot_be_retimed(arrival, message):
    with pytest.raises(RetimingError, match=message):
        retime(arrival)


@given(st.lists(st.one_of(st.just(0.0), st.floats(1e-6, 0.05), st.floats(0.05, 5.0)), min_size=19, max_size=400),
       st.floats(0.0, 2e9))
def test_any_non_decreasing_arrivals_give_increasing_causal_times(increments, start):
    arrival = start + np.concatenate([[0.0], np.cumsum(increments)])
    assume(arrival[-1] > arrival[0])
    try:
        r = retime(arrival)
    except RetimingError as err:  # the one refusal allowed: nothing to read a rate from
        assert "show no sample rate" in str(err)
        return
    assert np.all(np.diff(r.t_s) > 0) and np.all(np.isfinite(r.t_s))
    assert np.all(r.t_s <= arrival + 1e-6 * max(1.0, abs(start) * 1e-9))
    assert np.all(r.lost_before >= 0) and np.all(np.diff(r.sample_index) >= 1)
    assert r.period_s > 0 and np.all(r.delay_s >= -1e-6)


def test_a_signal_logged_at_other_times_onto_the_sample_clock():
    t_logged = np.array([0.0, 0.1, 0.1, 0.25, 0.4, 0.5])  # arrival times: bursts share a stamp
    values = np.array([1.0, 2.0, 2.0, np.nan, 5.0, 6.0])  # an empty cell is skipped
    t_s = np.array([-0.05, 0.0, 0.05, 0.25, 0.45, 0.5, 0.6])
    np.testing.assert_allclose(on_sample_clock(t_logged, values, t_s),
                               [np.nan, 1.0, 1.5, 3.5, 5.5, 6.0, np.nan])  # never extrapolated
    assert np.isnan(on_sample_clock([0.0, 1.0], [np.nan, 2.0], [0.5])).all()  # one value: unknown
