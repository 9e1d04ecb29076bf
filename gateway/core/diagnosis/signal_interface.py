"""The interface of a signal effect (`SignalEffect`), the model state it changes stage by
stage (`Signal`), what the estimator does differently when it knows one (`Compensation`),
and the two ways an effect finds its starting values (a linear fit, a grid).

The stages, in physical order, and the effects themselves: signal_effects.py.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gateway.core.diagnosis.context import Prepared
from gateway.core.model_compensation import SampleContext


@dataclass
class Signal:
    """The model's state between stages."""

    # the baseline sensor's reading of the motion (m/s²) on the full sample grid: lost
    # samples included, so the filters of stage 1 run through gaps as the sensor did
    full: np.ndarray
    where: np.ndarray  # the received samples' places in it
    pos_m: np.ndarray | None
    out: np.ndarray | None = None  # the predicted measurement (received samples), from stage 2 on

    @property
    def reading(self) -> np.ndarray:
        return self.full[self.where]

    def copy(self) -> Signal:
        return Signal(self.full.copy(), self.where, None if self.pos_m is None else self.pos_m.copy())


@dataclass
class Compensation:
    """What the estimator does differently when it knows the effect."""

    acc_mps2: np.ndarray | None = None  # corrected measurement
    invalid: np.ndarray | None = None  # samples to treat as missing
    settings: dict = field(default_factory=dict)  # EstimatorSettings overrides
    ref_shift_s: float = 0.0  # the reference is read this much later
    note: str = ""


class SignalEffect:
    name = ""
    summary = ""
    stage = 2
    param_names: tuple[str, ...] = ()
    # a property every setup has (fitted inside its range, reported as measured, never named)
    setup_only = False

    def unusable(self, prep: Prepared) -> str | None:
        """Why this effect cannot be looked for in this recording (None: it can)."""
        return None if prep.data.reference == "recorded" else "needs the recorded reference motion"

    def initial(self, prep: Prepared, residual: np.ndarray, sig: Signal) -> np.ndarray:
        raise NotImplementedError

    def bounds(self, prep: Prepared) -> tuple[list[float], list[float]]:
        n = len(self.param_names)
        return [-np.inf] * n, [np.inf] * n

    def apply(self, prep: Prepared, theta: np.ndarray, sig: Signal) -> None:
        raise NotImplementedError

    def report(self, theta: np.ndarray, std: np.ndarray) -> dict[str, tuple[float, float]]:
        return {n: (float(v), float(s)) for n, v, s in zip(self.param_names, theta, std, strict=False)}

    def compensate(self, prep: Prepared, theta: np.ndarray, acc: np.ndarray, est: SampleContext) -> Compensation | None:
        return None

    def model_params(self, prep: Prepared, theta: np.ndarray) -> dict[str, float]:
        """The parameters as the model file keeps them (SI units; model_compensation reads them)."""
        return {n: float(v) for n, v in zip(self.param_names, theta, strict=False)}

    def full_scale_gain(self, theta: np.ndarray) -> float:
        """How this effect changes where the part's saturation reads (1: not at all)."""
        return 1.0


def _ls_coefficient(residual: np.ndarray, regressor: np.ndarray, mask: np.ndarray) -> float:
    x = regressor[mask] - regressor[mask].mean()
    y = residual[mask] - residual[mask].mean()
    den = float(np.dot(x, x))
    return float(np.dot(x, y)) / den if den > 0 else 0.0


def _grid_with_free_gains(prep: Prepared, residual, grid, columns):
    """For an effect linear in some parameters (gains) and not in others: over a grid of
    the others, the gains of `columns(point)` (regressors on the residual's samples) by
    least squares on the residual, means removed. Returns the point and its gains that
    leave the least squared misfit, or None when no point gives a finite one."""
    m = prep.fit_mask
    y = residual[m] - residual[m].mean()
    best, best_cost = None, np.inf
    for point in grid:
        x = np.column_stack([c[m] for c in columns(point)])
        x = x - x.mean(axis=0)
        gains = np.linalg.lstsq(x, y, rcond=None)[0]
        cost = float(np.sum((y - x @ gains) ** 2))
        if cost < best_cost:
            best, best_cost = (tuple(point), tuple(float(g) for g in gains)), cost
    return best


def _grid_best(prep: Prepared, residual, sig: Signal, effect, grid):
    """The grid point whose model change best explains the residual (with a free scale)."""
    best, best_cost = grid[0], np.inf
    m = prep.fit_mask
    for theta in grid:
        trial = sig.copy()
        effect.apply(prep, np.asarray(theta, dtype=float), trial)
        delta = trial.reading - sig.reading
        r = residual - delta
        r = r[m] - r[m].mean()
        cost = float(np.dot(r, r))
        if cost < best_cost:
            best, best_cost = theta, cost
    return np.asarray(best, dtype=float)
