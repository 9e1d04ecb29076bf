"""Linear filters on the sample grid, shared by the simulator's error terms and the diagnosis.

Both describe the same physics (a sensor's low-pass, a flexible mount), so both use one
implementation; the diagnosis still never sees which effect a simulation hid.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import bilinear, lfilter, lfilter_zi


def one_pole_lowpass(u: np.ndarray, period_s: float, bandwidth_hz: float) -> np.ndarray:
    """y_k = a·y_(k−1) + (1 − a)·u_k, a = e^(−2π f Ts), started settled at u_0."""
    a = math.exp(-2.0 * math.pi * bandwidth_hz * period_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], u, zi=[a * u[0]] if u.size else [0.0])
    return y


def moved_pole(y: np.ndarray, period_s: float, from_hz: float, to_hz: float) -> np.ndarray:
    """What one_pole_lowpass at to_hz would have given, from its output at from_hz: that
    pole undone and the other applied — the lead-lag (1 − a₀z⁻¹)(1 − a₁) / ((1 − a₀)(1 − a₁z⁻¹)),
    DC gain 1, started settled at y_0."""
    a0 = math.exp(-2.0 * math.pi * from_hz * period_s)
    a1 = math.exp(-2.0 * math.pi * to_hz * period_s)
    gain = (1.0 - a1) / (1.0 - a0)
    b, a = [gain, -gain * a0], [1.0, -a1]
    out, _ = lfilter(b, a, y, zi=lfilter_zi(b, a) * y[0] if y.size else [0.0])
    return out


def mount_resonance(x: np.ndarray, period_s: float, f0_hz: float, damping: float) -> np.ndarray:
    """A sensor on a flexible mount follows its base through (2ζωs + ω²)/(s² + 2ζωs + ω²).

    Bilinear transform, pre-warped so the discrete resonance sits at f0; started settled
    at x_0 (DC gain 1).
    """
    fs = 1.0 / period_s
    wp = 2.0 * fs * math.tan(math.pi * f0_hz / fs)
    b, a = bilinear([2.0 * damping * wp, wp * wp], [1.0, 2.0 * damping * wp, wp * wp], fs=fs)
    y, _ = lfilter(b, a, x, zi=lfilter_zi(b, a) * (x[0] if x.size else 0.0))
    return y
