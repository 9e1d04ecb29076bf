"""Reference motions along one axis, in closed form.

A profile is a list of segments of constant acceleration; position, velocity and
acceleration are then exact at any time (no integration error in the truth).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Segment:
    duration_s: float
    acc_mps2: float


class PiecewiseConstantAcceleration:
    """Exact kinematics of a sequence of constant-acceleration segments, starting at rest at 0."""

    def __init__(self, segments: list[Segment]):
        segments = [s for s in segments if s.duration_s > 0]
        if not segments:
            raise ValueError("a motion profile needs at least one segment of positive duration")
        self.segments = tuple(segments)
        durations = np.array([s.duration_s for s in segments])
        self._acc = np.array([s.acc_mps2 for s in segments])
        self._t0 = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
        # state at the start of each segment
        v0 = np.zeros(len(segments))
        p0 = np.zeros(len(segments))
        for i in range(1, len(segments)):
            d = durations[i - 1]
            v0[i] = v0[i - 1] + self._acc[i - 1] * d
            p0[i] = p0[i - 1] + v0[i - 1] * d + 0.5 * self._acc[i - 1] * d * d
        self._v0, self._p0 = v0, p0
        self.duration_s = float(np.sum(durations))

    def evaluate(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (m), velocity (m/s), acceleration (m/s²) at times t_s (clamped to the profile)."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        i = np.searchsorted(self._t0, t, side="right") - 1
        dt = t - self._t0[i]
        a = self._acc[i]
        vel = self._v0[i] + a * dt
        pos = self._p0[i] + self._v0[i] * dt + 0.5 * a * dt * dt
        return pos, vel, a.copy()

    def standstill_intervals(self) -> list[tuple[float, float]]:
        """Intervals (start_s, end_s) where the body is at rest (zero velocity and acceleration)."""
        out = []
        for t0, v0, seg in zip(self._t0, self._v0, self.segments, strict=False):
            if seg.acc_mps2 == 0.0 and abs(v0) < 1e-12:
                out.append((float(t0), float(t0 + seg.duration_s)))
        return out


def _move(distance_m: float, max_speed_mps: float, max_acc_mps2: float) -> list[Segment]:
    """Trapezoidal (or triangular, if the distance is short) velocity profile of a move."""
    if max_speed_mps <= 0 or max_acc_mps2 <= 0:
        raise ValueError("speed and acceleration must be positive")
    sign = 1.0 if distance_m >= 0 else -1.0
    d = abs(distance_m)
    t_acc = max_speed_mps / max_acc_mps2
    if max_acc_mps2 * t_acc * t_acc >= d:  # never reaches max speed
        t_acc = math.sqrt(d / max_acc_mps2)
        t_cruise = 0.0
    else:
        t_cruise = (d - max_acc_mps2 * t_acc * t_acc) / max_speed_mps
    return [
        Segment(t_acc, sign * max_acc_mps2),
        Segment(t_cruise, 0.0),
        Segment(t_acc, -sign * max_acc_mps2),
    ]


@dataclass(frozen=True)
class StrokeSettings:
    """The paper's experiment (Lee & Park, §2.3): 30 cm back and forth, 1 m/s, 10 m/s².

    Dwell and rest times are not given in the paper; the defaults leave a standstill
    long enough to see (1 s) at each end and a rest at the start for reference-point
    compensation (2 s).
    """

    stroke_m: float = 0.30
    max_speed_mps: float = 1.0
    max_acc_mps2: float = 10.0
    strokes: int = 10
    dwell_s: float = 1.0
    rest_start_s: float = 2.0
    rest_end_s: float = 1.0
    # 0: acceleration steps (the paper's drive); > 0: a jerk-limited (S-curve) drive,
    # as servo drives and robot controllers move (jerk_limited)
    jerk_mps3: float = 0.0


def reciprocating_strokes(s: StrokeSettings = StrokeSettings()) -> PiecewiseConstantAcceleration:
    """Rest, then `strokes` one-way moves alternating forward and back, a dwell after each."""
    if s.strokes < 1:
        raise ValueError("strokes must be at least 1")
    segments = [Segment(s.rest_start_s, 0.0)]
    for k in range(s.strokes):
        direction = 1.0 if k % 2 == 0 else -1.0
        segments += _move(direction * s.stroke_m, s.max_speed_mps, s.max_acc_mps2)
        dwell = s.dwell_s if k < s.strokes - 1 else s.rest_end_s
        segments.append(Segment(dwell, 0.0))
    return jerk_limited(PiecewiseConstantAcceleration(segments), s.jerk_mps3)


# ramp steps of a jerk-limited profile: a ramp of 25 ms (10 m/s² at 400 m/s³) in steps of
# ~3 ms, finer than a 500 Hz sample and than the sensor filter's 3.2 ms time constant
JERK_RAMP_STEPS = 8


def jerk_limited(profile: PiecewiseConstantAcceleration, jerk_mps3: float,
                 steps: int = JERK_RAMP_STEPS) -> PiecewiseConstantAcceleration:
    """The profile as a jerk-limited drive moves it: in every move (the segments between two
    rests) each acceleration step becomes a ramp of t_j = a_max / jerk (a_max the move's
    largest |acceleration|) — the move's acceleration averaged over `steps` copies of it
    shifted evenly across t_j.

    Why this form: the simulator's sensor filter is exact for constant pieces
    (simulator.period_mean_lowpass), so a ramp is a staircase of `steps` steps of t_j/steps
    (max jerk a_max/t_j on average). Averaging copies of a move that starts and ends at
    rest keeps its displacement and peak acceleration; each move lasts t_j·(steps−1)/steps
    longer, and the rests keep their lengths (a 0.1 s stop stays 0.1 s). jerk_mps3 ≤ 0:
    the profile unchanged."""
    if not jerk_mps3 > 0:
        return profile
    if steps < 1:
        raise ValueError("a jerk-limited profile needs at least one step per ramp")
    segments: list[Segment] = []
    move: list[Segment] = []
    for seg, v0 in zip(profile.segments, profile._v0, strict=False):
        if seg.acc_mps2 == 0.0 and abs(v0) < 1e-12:  # a rest: the move before it ends here
            segments += _ramped_move(move, jerk_mps3, steps) + [seg]
            move = []
        else:
            move.append(seg)
    segments += _ramped_move(move, jerk_mps3, steps)
    return PiecewiseConstantAcceleration(segments)


def _ramped_move(move: list[Segment], jerk_mps3: float, steps: int) -> list[Segment]:
    """One move's segments with its acceleration averaged over `steps` shifted copies."""
    if not move:
        return []
    durations = np.array([seg.duration_s for seg in move])
    acc = np.array([seg.acc_mps2 for seg in move])
    peak = float(np.max(np.abs(acc)))
    if peak == 0.0:
        return list(move)
    starts = np.concatenate([[0.0], np.cumsum(durations)])
    shifts = np.arange(steps) * (peak / jerk_mps3) / steps
    edges = np.unique(np.concatenate([starts + d for d in shifts]))
    mids = 0.5 * (edges[:-1] + edges[1:])
    mean_acc = np.zeros(mids.size)
    for d in shifts:
        i = np.searchsorted(starts, mids - d, side="right") - 1
        inside = (i >= 0) & (i < acc.size)
        mean_acc[inside] += acc[i[inside]]
    mean_acc /= steps
    mean_acc[np.abs(mean_acc) < 1e-9 * peak] = 0.0  # a cruise's exact zero
    out: list[Segment] = []
    for duration, a in zip(np.diff(edges), mean_acc, strict=False):
        if out and out[-1].acc_mps2 == a:  # pieces of equal acceleration joined
            out[-1] = Segment(out[-1].duration_s + duration, a)
        else:
            out.append(Segment(float(duration), float(a)))
    return out


def single_move(
    distance_m: float = 0.30,
    max_speed_mps: float = 1.0,
    max_acc_mps2: float = 10.0,
    rest_start_s: float = 2.0,
    rest_end_s: float = 2.0,
    jerk_mps3: float = 0.0,
) -> PiecewiseConstantAcceleration:
    return jerk_limited(PiecewiseConstantAcceleration(
        [Segment(rest_start_s, 0.0)]
        + _move(distance_m, max_speed_mps, max_acc_mps2)
        + [Segment(rest_end_s, 0.0)]
    ), jerk_mps3)


def standstill(duration_s: float) -> PiecewiseConstantAcceleration:
    """At rest for the whole run: for zero-drift studies (the paper's 12-hour record)."""
    return PiecewiseConstantAcceleration([Segment(duration_s, 0.0)])
