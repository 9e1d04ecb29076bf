"""The baseline plus a set of signal effects, fitted jointly to the measured axis.

Parameters: the baseline's zero-g offset and drift amplitude (linear), then each
effect's own. The fit minimises the whitened residual (scipy least_squares), which is
maximum likelihood under the ARMA(1,1) noise model; standard deviations come from the
Jacobian at the optimum, scaled by the whitened residual's variance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from gateway.core.diagnosis.context import Prepared
from gateway.core.diagnosis.criterion import CvGain, block_ids, block_predictive_loglik, cv_gain
from gateway.core.diagnosis.reading import gaussian_loglik
from gateway.core.diagnosis.signal_interface import Signal, SignalEffect

BASELINE_PARAMS = ("offset_mps2", "drift_mps2")


@dataclass
class ModelFit:
    effects: tuple[SignalEffect, ...]
    theta: np.ndarray  # baseline's two, then each effect's
    std: np.ndarray
    residual: np.ndarray  # measured − model, all samples (NaN where invalid)
    whitened: np.ndarray  # over the fit mask
    loglik: float
    n_params: int

    @property
    def n(self) -> int:
        return int(self.whitened.size)

    @property
    def bic(self) -> float:
        return -2.0 * self.loglik + self.n_params * np.log(self.n)

    block: int = 1  # the comparison's block (Prepared.block): the RMS is taken at that rate
    # the whitened residual's Jacobian in the free parameters (criterion.py: out-of-block prediction)
    jacobian: np.ndarray | None = None

    @property
    def residual_rms(self) -> float:
        r = self.residual
        if self.block > 1:
            n = r.size // self.block * self.block
            blocks = r[:n].reshape(-1, self.block)
            r = blocks[np.isfinite(blocks).all(axis=1)].mean(axis=1)
        r = r[np.isfinite(r)]
        return float(np.sqrt(np.mean((r - r.mean()) ** 2))) if r.size else float("nan")

    def effect_theta(self, effect: SignalEffect) -> tuple[np.ndarray, np.ndarray]:
        i = len(BASELINE_PARAMS)
        for e in self.effects:
            k = len(e.param_names)
            if e is effect:
                return self.theta[i:i + k], self.std[i:i + k]
            i += k
        raise KeyError(effect.name)

    def baseline_params(self) -> dict[str, tuple[float, float]]:
        return {n: (float(self.theta[i]), float(self.std[i])) for i, n in enumerate(BASELINE_PARAMS)}


def _ordered(effects):
    return tuple(sorted(effects, key=lambda e: e.stage))


def predict(prep: Prepared, effects: tuple[SignalEffect, ...], theta: np.ndarray) -> np.ndarray:
    ref = None if prep.data.ref_pos_m is None else prep.data.ref_pos_m.copy()
    sig = Signal(prep.reading_full.copy(), prep.where, ref)
    chunks, i = [], len(BASELINE_PARAMS)
    for e in effects:
        k = len(e.param_names)
        chunks.append(theta[i:i + k])
        i += k
    for e, th in zip(effects, chunks, strict=False):
        if e.stage < 2:
            e.apply(prep, th, sig)
    sig.out = sig.reading + theta[0] + theta[1] * prep.drift_shape
    for e, th in zip(effects, chunks, strict=False):
        if e.stage >= 2:
            e.apply(prep, th, sig)
    # the baseline sensor saturates at its range too (the simulator clips at ±2 g), read
    # through what the effects make of full scale (the part's own sensitivity)
    r = prep.data.range_mps2 * math.prod(e.full_scale_gain(th) for e, th in zip(effects, chunks, strict=False))
    return np.clip(sig.out, -r, r)


def _whitened(prep: Prepared, residual: np.ndarray) -> np.ndarray:
    return prep.whiten_masked(residual, prep.fit_mask)


def fit_model(prep: Prepared, effects, start: dict[str, np.ndarray] | None = None,
              base_start: np.ndarray | None = None) -> ModelFit:
    """Fit the baseline with these effects; start: initial values per effect name."""
    effects = _ordered(effects)
    start = start or {}
    measured = prep.data.acc_mps2
    m = prep.fit_mask
    if base_start is None:
        x = np.column_stack([np.ones(m.sum()), prep.drift_shape[m]])
        base_start = np.linalg.lstsq(x, measured[m] - prep.reading_mps2[m], rcond=None)[0]
    x0 = [np.asarray(base_start, dtype=float)]
    lo, hi = [[-np.inf] * 2], [[np.inf] * 2]
    for e in effects:
        x0.append(np.asarray(start[e.name], dtype=float))
        b = e.bounds(prep)
        lo.append(b[0])
        hi.append(b[1])
    x0 = np.concatenate(x0)
    lo, hi = np.concatenate(lo), np.concatenate(hi)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.minimum(np.maximum(x0, np.where(np.isfinite(lo), lo + 1e-6 * span, lo)),
                    np.where(np.isfinite(hi), hi - 1e-6 * span, hi))
    filled = np.where(m, measured, 0.0)

    def fun(theta):
        return _whitened(prep, filled - predict(prep, effects, theta))

    if effects:
        sol = least_squares(fun, x0, bounds=(lo, hi), x_scale="jac", method="trf", max_nfev=200)
        theta, jac = sol.x, sol.jac
    else:
        theta = x0
        jac = None
    residual = np.where(m, measured - predict(prep, effects, theta), np.nan)
    white = _whitened(prep, np.nan_to_num(residual))
    if jac is None:
        # linear: the Jacobian of the whitened residual is the whitened regressors
        cols = [np.ones(m.size), prep.drift_shape]
        jac = -np.column_stack([_whitened(prep, c) for c in cols])
    # a parameter at a bound of its range is held there: no column for it
    span_all = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    free = ~((np.isfinite(lo) & (theta - lo <= 1e-5 * span_all)) | (np.isfinite(hi) & (hi - theta <= 1e-5 * span_all)))
    jac_free = np.asarray(jac)[:, free] if jac is not None else None
    var = float(np.dot(white, white)) / max(white.size - theta.size, 1)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * var
        std = np.sqrt(np.clip(np.diag(cov), 0.0, np.inf))
    except np.linalg.LinAlgError:
        std = np.full(theta.size, np.nan)
    return ModelFit(effects, theta, std, residual, white, gaussian_loglik(white), theta.size, prep.block, jac_free)


def cv_gain_of(prep: Prepared, with_effect: ModelFit, without: ModelFit) -> CvGain:
    """The out-of-block predictive gain of one model over another (criterion.py)."""
    ids = block_ids(prep.compared_index(prep.fit_mask), prep.rest)
    return cv_gain(block_predictive_loglik(with_effect.whitened, with_effect.jacobian, ids),
                   block_predictive_loglik(without.whitened, without.jacobian, ids))


def current_signal(prep: Prepared, fit: ModelFit) -> Signal:
    """The motion's reading with the accepted filters and delay applied (what new effects act on)."""
    ref = None if prep.data.ref_pos_m is None else prep.data.ref_pos_m.copy()
    sig = Signal(prep.reading_full.copy(), prep.where, ref)
    i = len(BASELINE_PARAMS)
    for e in fit.effects:
        k = len(e.param_names)
        if e.stage < 2:
            e.apply(prep, fit.theta[i:i + k], sig)
        i += k
    return sig
