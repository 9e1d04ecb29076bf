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
        for t0, v0, seg in zip(self._t0, self._v0, self.segments):
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
    return PiecewiseConstantAcceleration(segments)


def single_move(
    distance_m: float = 0.30,
    max_speed_mps: float = 1.0,
    max_acc_mps2: float = 10.0,
    rest_start_s: float = 2.0,
    rest_end_s: float = 2.0,
) -> PiecewiseConstantAcceleration:
    return PiecewiseConstantAcceleration(
        [Segment(rest_start_s, 0.0)]
        + _move(distance_m, max_speed_mps, max_acc_mps2)
        + [Segment(rest_end_s, 0.0)]
    )


def standstill(duration_s: float) -> PiecewiseConstantAcceleration:
    """At rest for the whole run: for zero-drift studies (the paper's 12-hour record)."""
    return PiecewiseConstantAcceleration([Segment(duration_s, 0.0)])
