"""The smoothed estimate decides its stops from both sides of the record.

After an offset step in a long cruise the forward filter no longer knows its velocity
and cannot call the next stops stops (flag 256); the smoothed estimate used to inherit
that (metres off). The same filter run backward from the final rest, with the bias
measured there, recognises them, and the forward pass takes them as a rest hint
(estimator_passes.stops_seen_from_the_end). All on the simulator's robot-like path.
"""
import numpy as np
import pytest

from gateway.core import estimator_kernel as K
from gateway.core.estimator import estimate_series, lost_from_times
from gateway.core.estimator_passes import lost_before_reversed
from testing.robot_like_cases import robot_case, worst_move_and_inside


@pytest.mark.parametrize("seed", range(3))
def test_an_offset_step_in_a_cruise_no_longer_ruins_the_smoothed_estimate(seed):
    t, z, ref, resting, settings = robot_case(seed, 5.0)
    realtime = estimate_series(t, z, method="realtime", settings=settings)
    smoothed = estimate_series(t, z, method="smoothed", settings=settings)
    worst_rt, _ = worst_move_and_inside(realtime, ref, resting)
    worst_sm, inside = worst_move_and_inside(smoothed, ref, resting)
    assert worst_rt > 100.0 and realtime.untrusted.any()  # the forward filter cannot, and says so
    assert worst_sm < 3.0 and inside, (worst_sm, inside)
    assert any("running backward from the final rest" in n for n in smoothed.notes)
    # the backward run's stops are not the machine's hint: no hint flags without one
    assert not np.any(smoothed.flags & (K.F_HINT_REST | K.F_HINT_CONFLICT))
    # the forward pass could not confirm the final rest (its velocity was lost): the
    # estimate rests on taking the quiet end for a rest, and stays flagged where it did
    assert not realtime.standstill[-1]
    assert np.array_equal(smoothed.untrusted, smoothed.untrusted | realtime.untrusted)


def test_without_a_lost_velocity_the_smoothed_estimate_is_the_one_pass_smoother():
    t, z, ref, resting, settings = robot_case(0, 0.0, rate_hz=500.0, noise_mps2=0.005)
    smoothed = estimate_series(t, z, method="smoothed", settings=settings)
    assert not any("running backward" in n for n in smoothed.notes)
    assert worst_move_and_inside(smoothed, ref, resting)[0] < 1.0


@pytest.mark.parametrize("seed", range(3))
def test_a_recording_that_ends_in_a_cruise_is_flagged_with_an_uncertainty_that_covers_it(seed):
    t, z, ref, resting, settings = robot_case(seed, 5.0)
    # cut inside the last move's cruise: the quiet end is no rest, and the forward pass
    # (its velocity lost to the offset step) cannot tell; the backward run takes it for one
    last_cruise = np.flatnonzero((np.abs(np.gradient(ref, t)) > 0.15) & (t > t[-1] - 5.0))
    cut = int(last_cruise[len(last_cruise) // 2])
    t, z, ref, resting = t[:cut], z[:cut], ref[:cut], resting[:cut]
    realtime = estimate_series(t, z, method="realtime", settings=settings)
    smoothed = estimate_series(t, z, method="smoothed", settings=settings)
    assert any("taken for a rest, which the forward pass could not confirm" in n for n in smoothed.notes)
    ends = np.array([b - 1 for b in np.flatnonzero(np.diff(resting.astype(int)) == -1) + 1] + [t.size - 1])
    err = np.abs(smoothed.pos_m[ends] - ref[ends])
    assert np.all(err <= 3 * smoothed.pos_std_m[ends] + 1e-4), (err, smoothed.pos_std_m[ends])
    assert smoothed.untrusted[realtime.untrusted].all()


def test_lost_samples_read_backward_are_the_same_gaps():
    rng = np.random.default_rng(3)
    k = np.cumsum(1 + (rng.random(400) < 0.05) * rng.integers(1, 4, 400))  # some samples lost
    t = k * 0.002
    lost = lost_from_times(t)
    assert lost.sum() > 0
    np.testing.assert_array_equal(lost_from_times(t[-1] - t[::-1]), lost_before_reversed(lost))


@pytest.mark.parametrize("seed", range(3))
def test_a_recording_scored_a_tenth_of_a_second_into_its_last_rest_is_not_read_backward(seed):
    """The horizontal robot runs end 0.11–0.16 s into their last rest: the last 0.2 s hold
    the deceleration, so the recording does not end at a rest the backward run could start
    from (estimator_passes.ends_at_rest). Measured on the record's own first samples, that
    deceleration's spread passed for the rest's noise and the whole record for its "final
    rest": the backward run started inside the last cruise and took it for a stop."""
    t, z, ref, resting, settings = robot_case(seed, 5.0)
    last_rest = int(np.flatnonzero(np.diff(resting.astype(int)) == 1)[-1]) + 1  # the final rest's first sample
    cut = int(np.searchsorted(t, t[last_rest] + 0.13))
    t, z, ref, resting = t[:cut], z[:cut], ref[:cut], resting[:cut]
    realtime = estimate_series(t, z, method="realtime", settings=settings)
    smoothed = estimate_series(t, z, method="smoothed", settings=settings)
    assert not any("running backward" in n for n in smoothed.notes), smoothed.notes
    assert not realtime.standstill[-1]
    # no stop inside the last move: the smoothed velocity there is not zeroed
    moving = np.flatnonzero(np.abs(np.gradient(ref, t)) > 0.15)
    last_move = moving[moving > int(np.flatnonzero(np.diff(resting.astype(int)) == -1)[-1])]
    assert not smoothed.standstill[last_move].any()
