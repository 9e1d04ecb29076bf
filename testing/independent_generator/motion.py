"""Jerk-limited (S-curve) point-to-point moves, evaluated exactly on any time grid.

A move of distance D with limits v_max, a_max, j_max is the classic seven-phase
profile: jerk +j, 0, −j (acceleration up to a_peak and back), cruise, then the mirror
image. Short moves lower the peak velocity (and the peak acceleration) until the
profile fits. Acceleration is piecewise linear, velocity and position follow in closed
form by integrating each phase's polynomial.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MoveLimits:
    v_max_mps: float = 1.0
    a_max_mps2: float = 10.0
    j_max_mps3: float = 400.0


def _phases(distance_m: float, lim: MoveLimits) -> list[tuple[float, float]]:
    """(duration s, jerk m/s³) per phase for a move of |distance| in the + direction."""
    d = abs(distance_m)
    j = lim.j_max_mps3

    def accel_part(v_peak):
        a_peak = min(lim.a_max_mps2, math.sqrt(v_peak * j))
        tj = a_peak / j
        ta = v_peak / a_peak - tj  # hold time at a_peak
        dist = v_peak * (2 * tj + ta) / 2.0  # symmetric ramp: mean velocity v/2
        return tj, ta, dist

    lo, hi = 0.0, lim.v_max_mps
    tj, ta, dist = accel_part(hi)
    if 2 * dist > d:  # cannot reach v_max: bisect the peak velocity
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if 2 * accel_part(mid)[2] > d:
                hi = mid
            else:
                lo = mid
        tj, ta, dist = accel_part(lo)
        v = lo
    else:
        v = hi
    tc = max(0.0, (d - 2 * dist) / v) if v > 0 else 0.0
    return [(tj, j), (ta, 0.0), (tj, -j), (tc, 0.0), (tj, -j), (ta, 0.0), (tj, j)]


@dataclass
class MotionPlan:
    """Moves (start time, distance) on one axis, evaluated piecewise-polynomially."""

    limits: MoveLimits
    moves: list[tuple[float, float]]

    def knots(self):
        """Times where the jerk changes, with the jerk after each (0 between moves)."""
        t, jerk = [], []
        for start, dist in self.moves:
            sign = 1.0 if dist >= 0 else -1.0
            tt = start
            for dur, j in _phases(dist, self.limits):
                if dur <= 0:
                    continue
                t.append(tt)
                jerk.append(sign * j)
                tt += dur
            t.append(tt)
            jerk.append(0.0)
        return np.asarray(t), np.asarray(jerk)

    def end_s(self) -> float:
        t, _ = self.knots()
        return float(t[-1]) if t.size else 0.0

    def evaluate(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position m, velocity m/s, acceleration m/s²) at the times t_s (sorted)."""
        t_s = np.asarray(t_s, dtype=float)
        kt, kj = self.knots()
        pos = np.zeros_like(t_s)
        vel = np.zeros_like(t_s)
        acc = np.zeros_like(t_s)
        if kt.size == 0:
            return pos, vel, acc
        # state at each knot, integrating the constant jerk of each interval exactly
        state = np.zeros((kt.size, 3))  # p, v, a at knot i
        for i in range(1, kt.size):
            h = kt[i] - kt[i - 1]
            p, v, a = state[i - 1]
            j = kj[i - 1]
            state[i] = (p + v * h + a * h * h / 2 + j * h**3 / 6, v + a * h + j * h * h / 2, a + j * h)
        idx = np.searchsorted(kt, t_s, side="right") - 1
        before = idx < 0
        idx = np.maximum(idx, 0)
        h = t_s - kt[idx]
        p, v, a = state[idx, 0], state[idx, 1], state[idx, 2]
        j = kj[idx]
        pos = np.where(before, 0.0, p + v * h + a * h * h / 2 + j * h**3 / 6)
        vel = np.where(before, 0.0, v + a * h + j * h * h / 2)
        acc = np.where(before, 0.0, a + j * h)
        return pos, vel, acc


def strokes(rng: np.random.Generator, n: int, distance_m: float = 0.3, first_s: float = 1.0,
            rest_s=(0.6, 1.0), limits: MoveLimits = MoveLimits()) -> MotionPlan:
    """n back-and-forth strokes with random rests between them."""
    plan = MotionPlan(limits, [])
    t = first_s
    for k in range(n):
        d = distance_m if k % 2 == 0 else -distance_m
        plan.moves.append((t, d))
        t = plan.end_s() + float(rng.uniform(*rest_s))
    return plan
