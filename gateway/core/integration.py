"""Raw double integration (the paper's fig. 6): no compensation at all."""
from __future__ import annotations

import numpy as np


def hold_invalid(acc_mps2, valid) -> np.ndarray:
    """Invalid samples take the last valid value (0 before the first)."""
    a = np.asarray(acc_mps2, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(a)
    idx = np.where(ok, np.arange(a.size), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, a[np.maximum(idx, 0)], 0.0)


def double_integrate(t_s, acc_mps2, valid=None):
    """Position and velocity at each sample time; sample k's acceleration acts over [t_k, t_(k+1)].

    The same scheme as the estimator's motion step: v += a·Δt, p += v·Δt + a·Δt²/2.
    """
    t = np.asarray(t_s, dtype=float)
    a = hold_invalid(acc_mps2, np.ones(t.size, bool) if valid is None else valid)
    dt = np.diff(t)
    vel = np.concatenate([[0.0], np.cumsum(a[:-1] * dt)])
    pos = np.concatenate([[0.0], np.cumsum(vel[:-1] * dt + 0.5 * a[:-1] * dt * dt)])
    return pos, vel
