"""The paper's zero-drift model: ε(t) = C1·(1 − e^(−t/T)) + C2 (values in g).

Lee & Park identify it from a 12-hour standstill (their fig. 1); the source prints a
garbled eq. 1 and a wrong constant in eq. 2 — see shared/spec/paper-and-sensor.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DriftModel:
    c1_g: float = 0.0
    c2_g: float = 0.0
    time_constant_s: float = 1800.0

    def __post_init__(self) -> None:
        if not self.time_constant_s > 0:
            raise ValueError(f"time_constant_s must be positive, got {self.time_constant_s}")

    @property
    def settled_g(self) -> float:
        return self.c1_g + self.c2_g


def drift_g(t_s, model: DriftModel) -> np.ndarray:
    """Closed form."""
    t = np.asarray(t_s, dtype=float)
    return model.c1_g * -np.expm1(-t / model.time_constant_s) + model.c2_g


def drift_step_exact(eps_g, period_s, model: DriftModel):
    """ε(k+1) = φ·ε(k) + (1 − φ)(C1 + C2), φ = e^(−Ts/T): exact for any period Ts."""
    phi = np.exp(-np.asarray(period_s, dtype=float) / model.time_constant_s)
    return phi * eps_g + (1.0 - phi) * model.settled_g


def drift_step_backward_euler(eps_g, period_s, model: DriftModel):
    """The paper's eq. 2 with its constant term corrected to Ts/(T+Ts)."""
    T = model.time_constant_s
    return T / (T + period_s) * eps_g + period_s / (T + period_s) * model.settled_g


def drift_recursive_g(periods_s, model: DriftModel, exact: bool = True) -> np.ndarray:
    """ε at the start of each period, by the recursion (ε(0) = C2)."""
    periods = np.asarray(periods_s, dtype=float)
    out = np.empty(periods.size)
    eps = model.c2_g
    step = drift_step_exact if exact else drift_step_backward_euler
    for k, ts in enumerate(periods):
        out[k] = eps
        eps = step(eps, ts, model)
    return out
