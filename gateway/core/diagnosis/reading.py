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


def sensor_reading(t_s, ref_vel_mps, ref_acc_mps2, bandwidth_hz: float | None) -> np.ndarray:
    """Period mean of the reference acceleration after a one-pole low-pass (None: no filter)."""
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(ref_vel_mps, dtype=float)
    a = np.asarray(ref_acc_mps2, dtype=float)
    n = t.size
    periods = np.diff(t)
    period = float(np.median(periods)) if n > 1 else 1.0
    mean = a.copy()
    if n > 1:
        regular = periods < 1.5 * period  # across a gap of lost samples, keep the start value
        mean[:-1] = np.where(regular, np.diff(v) / np.where(regular, periods, 1.0), a[:-1])
    if bandwidth_hz is None or not np.isfinite(bandwidth_hz):
        return mean
    tau = 1.0 / (2.0 * math.pi * bandwidth_hz)
    # fraction f of the period spent at the start value a_k (the rest at a_(k+1))
    nxt = np.append(a[1:], a[-1])
    step = nxt - a
    moved = np.abs(step) > 1e-12
    f = np.ones(n)
    f[moved] = np.clip((nxt[moved] - mean[moved]) / step[moved], 0.0, 1.0)
    decay = math.exp(-period / tau)
    # y at the period's end: start value decays, a_k acts for f·P then a_(k+1) for (1−f)·P
    tail = np.exp(-(1.0 - f) * period / tau)
    forcing = a * tail * (1.0 - np.exp(-f * period / tau)) + nxt * (1.0 - tail)
    y0 = a[0]  # settled: at rest (or steady) before the record starts
    y_end, _ = lfilter([1.0], [1.0, -decay], forcing, zi=[decay * y0])
    y_start = np.concatenate([[y0], y_end[:-1]])
    return mean - tau * (y_end - y_start) / period


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
