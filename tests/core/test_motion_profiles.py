import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from gateway.core.motion_profiles import (
    JERK_RAMP_STEPS,
    PiecewiseConstantAcceleration,
    Segment,
    StrokeSettings,
    jerk_limited,
    reciprocating_strokes,
    single_move,
    standstill,
)


def test_paper_stroke_matches_its_numbers():
    p = reciprocating_strokes(StrokeSettings(strokes=2, dwell_s=0.5, rest_start_s=1.0, rest_end_s=1.0))
    t = np.linspace(0, p.duration_s, 200001)
    pos, vel, acc = p.evaluate(t)
    assert pos.max() == pytest.approx(0.30, abs=1e-12)
    assert vel.max() == pytest.approx(1.0, abs=1e-12)
    assert np.abs(acc).max() == pytest.approx(10.0)
    assert pos[-1] == pytest.approx(0.0, abs=1e-12)  # back and forth
    # each move: 0.1 s accelerating, 0.2 s cruising, 0.1 s braking
    assert p.duration_s == pytest.approx(1.0 + 0.4 + 0.5 + 0.4 + 1.0)


def test_closed_form_agrees_with_numerical_integration():
    p = reciprocating_strokes(StrokeSettings(strokes=3))
    t = np.linspace(0, p.duration_s, 400001)
    pos, vel, acc = p.evaluate(t)
    v_num = cumulative_trapezoid(acc, t, initial=0)
    p_num = cumulative_trapezoid(vel, t, initial=0)
    assert np.max(np.abs(v_num - vel)) < 1e-3
    assert np.max(np.abs(p_num - pos)) < 1e-6


def test_short_move_is_triangular():
    p = single_move(distance_m=0.02, max_speed_mps=1.0, max_acc_mps2=10.0, rest_start_s=0, rest_end_s=0)
    _, vel, _ = p.evaluate(np.linspace(0, p.duration_s, 10001))
    assert vel.max() == pytest.approx(np.sqrt(0.02 * 10.0), rel=1e-6)
    assert p.evaluate(p.duration_s)[0] == pytest.approx(0.02)


def test_standstill_intervals_of_strokes():
    s = StrokeSettings(strokes=4, dwell_s=0.7, rest_start_s=2.0, rest_end_s=1.5)
    intervals = reciprocating_strokes(s).standstill_intervals()
    assert len(intervals) == 5
    assert intervals[0] == (0.0, 2.0)
    assert intervals[-1][1] - intervals[-1][0] == pytest.approx(1.5)


def test_standstill_is_at_rest():
    pos, vel, acc = standstill(10.0).evaluate(np.linspace(0, 10, 11))
    assert not pos.any() and not vel.any() and not acc.any()


def test_jerk_limited_strokes_keep_their_moves_and_rests():
    """An S-curve drive: the same strokes and peak acceleration, ramps of a_max/jerk in
    place of steps, the rests of their lengths (each move a ramp longer)."""
    steps = reciprocating_strokes(StrokeSettings(strokes=4))
    s = reciprocating_strokes(StrokeSettings(strokes=4, jerk_mps3=400.0))
    ramp_s = 10.0 / 400.0
    longer_s = ramp_s * (JERK_RAMP_STEPS - 1) / JERK_RAMP_STEPS
    t = np.linspace(0, s.duration_s, 400001)
    pos, vel, acc = s.evaluate(t)
    assert np.abs(acc).max() == pytest.approx(10.0)
    assert pos.max() == pytest.approx(0.30, abs=1e-9)
    assert pos[-1] == pytest.approx(0.0, abs=1e-12) and vel[-1] == pytest.approx(0.0, abs=1e-12)
    # no step larger than a ramp's staircase step: a_max / JERK_RAMP_STEPS
    assert np.max(np.abs(np.diff([seg.acc_mps2 for seg in s.segments]))) <= 10.0 / JERK_RAMP_STEPS + 1e-9
    # the ramp takes a_max / jerk: from rest to full acceleration
    first_move = np.flatnonzero(acc != 0)[0]
    full = np.flatnonzero(np.abs(acc) >= 10.0 - 1e-9)[0]
    assert t[full] - t[first_move] == pytest.approx(longer_s, abs=1e-4)
    before, after = steps.standstill_intervals(), s.standstill_intervals()
    assert len(after) == len(before)
    for k, ((a0, b0), (a1, b1)) in enumerate(zip(before, after, strict=False)):
        assert b1 - a1 == pytest.approx(b0 - a0, abs=1e-12)  # a rest keeps its length
        assert a1 == pytest.approx(a0 + k * longer_s, abs=1e-12)  # after k moves each a ramp longer
    assert s.duration_s == pytest.approx(steps.duration_s + 4 * longer_s)


def test_a_short_stop_stays_as_long():
    """A 0.1 s stop between two moves (the robot's path) keeps its 0.1 s."""
    p = PiecewiseConstantAcceleration([Segment(1.0, 0.0), Segment(0.2, 1.0), Segment(0.2, -1.0), Segment(0.1, 0.0),
                                       Segment(0.2, -1.0), Segment(0.2, 1.0), Segment(1.0, 0.0)])
    q = jerk_limited(p, 10.0)
    assert [round(b - a, 12) for a, b in q.standstill_intervals()] == [1.0, 0.1, 1.0]
    assert q.evaluate(q.duration_s)[0] == pytest.approx(0.0, abs=1e-12)


def test_no_jerk_limit_is_the_paper_drive():
    a = reciprocating_strokes(StrokeSettings(strokes=3))
    assert jerk_limited(a, 0.0) is a
    assert reciprocating_strokes(StrokeSettings(strokes=3, jerk_mps3=0.0)).segments == a.segments
