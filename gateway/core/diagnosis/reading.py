"""What the baseline sensor model says the board should have read, and its noise model.

The baseline is the simulator's own model (gateway/core/simulator.py): each sample is
the period mean of the reference acceleration after the sensor's one-pole CX filter,
plus zero-g offset and drift, plus noise. Here it is computed from a *recorded*
reference (ref_vel_mps, ref_acc_mps2 at each sample's start), not from a profile:

- the reference is read as piecewise constant with at most one step per period; the
  period mean of the unfiltered acceleration is exact from the velocity difference,
  m_k = (v_(k+1) − v_k)/P_k, and where the acceleration changes inside the period the
  step's position follows from m_k = f·a_k + (1 − f)·a_(k+1);
- the one-pole filter is then applied exactly to that piecewise-constant input
  (∫y = ∫u − τ·Δy over a period), as simulator.period_mean_lowpass does for a profile.

A smooth reference (a controller's log) is not piecewise constant; the reconstruction
then errs by the curvature within a period — far below the noise at 500 samples/s.

The noise of a residual is ARMA(1,1): the sensor's filtered noise is AR(1) (one pole),
the timer's quantisation adds white noise, and AR(1) + white = ARMA(1,1). Its two
coefficients are fitted on the rests (where no motion effect can act), and every model
is then compared on the *whitened* residual, whose samples are independent: that is
what makes a log-likelihood and a BIC honest at 500 samples/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.signal import lfilter


def reference_steps(t_s, ref_vel_mps, ref_acc_mps2):
    """The reference as piecewise-constant acceleration: (level before the record, step times, step sizes).

    Where a_k ≠ a_(k+1) one step lies inside period k; its position follows from the
    period mean m_k = (v_(k+1) − v_k)/P_k = f·a_k + (1 − f)·a_(k+1) — across a gap of
    lost samples too, exact when the gap holds one step.
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(ref_vel_mps, dtype=float)
    a = np.asarray(ref_acc_mps2, dtype=float)
    if t.size < 2:
        return float(a[0]) if a.size else 0.0, np.zeros(0), np.zeros(0)
    periods = np.diff(t)
    step = np.diff(a)
    k = np.flatnonzero(np.abs(step) > 1e-12)
    # across a gap of lost samples the same holds over the gap, if it holds one step
    mean = (v[k + 1] - v[k]) / periods[k]
    f = np.clip((a[k + 1] - mean) / step[k], 0.0, 1.0)
    return float(a[0]), t[k] + f * periods[k], step[k]


def reading_from_steps(t_s, level0: float, step_t, step_size, bandwidth_hz: float | None) -> np.ndarray:
    """Period means of a piecewise-constant acceleration after a one-pole low-pass, exactly.

    Over a period: ∫y = ∫u − τ·Δy (y' = (u − y)/τ); y at the period's end is the start
    value decayed plus each level's share. A step at fraction g of period k adds
    Δa·(1 − g) to the mean and Δa·(1 − e^(−(1−g)P/τ)) to the end value.
    """
    t = np.asarray(t_s, dtype=float)
    n = t.size
    period = float(np.median(np.diff(t))) if n > 1 else 1.0
    step_t = np.asarray(step_t, dtype=float)
    step_size = np.asarray(step_size, dtype=float)
    # level at each period start, and where each step falls
    cum = np.concatenate([[0.0], np.cumsum(step_size)])
    level = level0 + cum[np.searchsorted(step_t, t, side="right")]
    k = np.searchsorted(t, step_t, side="right") - 1
    g = np.where(k >= 0, (step_t - t[np.maximum(k, 0)]) / period, 0.0)
    late = g >= 1.0  # inside a gap: the step shows from the next sample on (already in level)
    inside = (k >= 0) & (k < n) & ~late
    k, g, size = k[inside], g[inside], step_size[inside]
    mean = level.copy()
    np.add.at(mean, k, size * (1.0 - g))
    if bandwidth_hz is None or not np.isfinite(bandwidth_hz):
        return mean
    tau = 1.0 / (2.0 * math.pi * bandwidth_hz)
    decay = math.exp(-period / tau)
    forcing = level * (1.0 - decay)
    np.add.at(forcing, k, size * -np.expm1(-(1.0 - g) * period / tau))
    y0 = level0  # settled before the record starts
    y_end, _ = lfilter([1.0], [1.0, -decay], forcing, zi=[decay * y0])
    y_start = np.concatenate([[y0], y_end[:-1]])
    return mean - tau * (y_end - y_start) / period


def sensor_reading(t_s, ref_vel_mps, ref_acc_mps2, bandwidth_hz: float | None, delay_s: float = 0.0) -> np.ndarray:
    """What the sensor reads of the reference motion; delay_s: the motion at t is the reference at t + d."""
    level0, step_t, step_size = reference_steps(t_s, ref_vel_mps, ref_acc_mps2)
    return reading_from_steps(t_s, level0, step_t - delay_s, step_size, bandwidth_hz)


def shifted(t_s, x, delay_s: float) -> np.ndarray:
    """x read delay_s later: x(t + delay_s), linear interpolation, held at the ends."""
    t = np.asarray(t_s, dtype=float)
    return np.interp(t + delay_s, t, x)


@dataclass(frozen=True)
class NoiseModel:
    """ARMA(1,1) of a residual: (1 − a·B)·r = (1 − θ·B)·e, e white."""

    ar: float
    ma: float

    def whiten(self, r: np.ndarray) -> np.ndarray:
        return lfilter([1.0, -self.ar], [1.0, -self.ma], r)

    @property
    def lag1(self) -> float:
        """Lag-1 autocorrelation of the ARMA process (how coloured the raw residual is)."""
        a, t = self.ar, self.ma
        return float((1 - a * t) * (a - t) / (1 + t * t - 2 * a * t)) if abs(a) < 1 else 1.0


WHITE = NoiseModel(0.0, 0.0)


def fit_noise_model(r: np.ndarray) -> NoiseModel:
    """Conditional least squares for (a, θ) on a residual with no motion effect in it."""
    r = np.asarray(r, dtype=float)
    r = r[np.isfinite(r)]
    if r.size < 64:
        return WHITE
    r = r - r.mean()

    def cost(p):
        e = lfilter([1.0, -p[0]], [1.0, -p[1]], r)
        return float(np.dot(e[1:], e[1:]))

    best = min(((a0, t0) for a0 in (0.0, 0.3, 0.6, 0.85) for t0 in (0.0, 0.3)), key=cost)
    res = minimize(cost, best, method="L-BFGS-B", bounds=[(-0.98, 0.98), (-0.98, 0.98)])
    return NoiseModel(float(res.x[0]), float(res.x[1]))


def gaussian_loglik(e: np.ndarray) -> float:
    """Log-likelihood of independent normal values with their ML variance."""
    n = e.size
    var = max(float(np.dot(e, e)) / n, 1e-300)
    return -0.5 * n * (math.log(2.0 * math.pi * var) + 1.0)
