"""The one criterion every signal effect is judged by: cross-validated predictive
likelihood over blocks of the record.

The record is cut into blocks that follow its structure — each rest and each stroke
(by the reference), long ones cut into equal pieces so that there are at least
MIN_CV_BLOCKS. Each block is predicted by the model fitted on all the others, with and
without the effect; the gain of block b is the difference of its predictive
log-likelihoods (whitened residual, Gaussian with the model's own variance).

The effect is predictive when the summed gain G exceeds what k parameters of an effect
that is not there gain by chance: their in-sample gain is ½χ²_k and leaving a block out
costs them about k (the out-of-sample penalty, as AIC's), so under the null
G ≈ ½χ²_k − k, and G > ½·χ²_k(α) − k has the false-alarm rate α. α is the diagnosis's
rate per round split over the candidates tried (Bonferroni): a clean record names
something with probability at most ALPHA per round. The spread of the block gains is
reported beside it (SE): an effect that lives in a few blocks (the acceleration phases)
has a wide spread by nature, so it informs, it does not decide.

Why this and not an in-sample test: an in-sample likelihood ratio grows with any shape
that fits a mismatch (thousands of samples make a tiny misfit "significant"); a block
predicted from the others gains only from what the effect has in common across the
record. A slow effect the offset and drift already take on every block gains nothing
out of block — and is not named (the report says what it could not be told from).

Leave-one-block-out is computed exactly for a model linear in its parameters and to
first order for the others, from the fit's Jacobian J (whitened): the residual of block
B predicted without it is (I − H_BB)⁻¹·e_B, H = J(JᵀJ)⁻¹Jᵀ (the block form of the
PRESS residual). Parameters at a bound of their range are held there (no column).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

# at least this many blocks: a record of a few rests and strokes is cut finer, so that
# no single block carries most of the record (leaving it out would leave the parameters
# to the rest) and the block gains' spread (the SE reported) has 19+ degrees of freedom
MIN_CV_BLOCKS = 20
# the false-alarm rate of one round of the search, split over the candidates tried: a
# clean record has an effect named with at most this probability per round
ALPHA = 1e-3


@dataclass(frozen=True)
class CvGain:
    total: float  # Σ over blocks of the predictive log-likelihood gain
    se: float  # its standard error from the block gains' spread
    blocks: int

    def threshold(self, alpha: float, k: int) -> float:
        """The gain k useless parameters exceed with probability alpha (module docstring)."""
        return 0.5 * float(chi2.isf(alpha, max(k, 1))) - max(k, 1)

    def predictive(self, alpha: float, k: int) -> bool:
        return bool(self.total > self.threshold(alpha, k))

    def text(self) -> str:
        return f"out-of-block log-likelihood gain {self.total:+.1f} ± {self.se:.1f} over {self.blocks} blocks"

    def to_dict(self) -> dict:
        return {"gain": self.total, "se": self.se, "blocks": self.blocks}


def block_ids(sample_index: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """A block number for each compared value (its sample's index): rests and strokes,
    long ones cut into pieces so that there are at least MIN_CV_BLOCKS blocks."""
    n = sample_index.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    state = np.asarray(rest, dtype=bool)[sample_index]
    change = np.flatnonzero(np.diff(state.astype(np.int8)) != 0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [n]])
    longest = max(1, int(math.ceil(n / MIN_CV_BLOCKS)))
    ids = np.empty(n, dtype=np.int64)
    k = 0
    for a, e in zip(starts, ends, strict=False):
        pieces = max(1, int(math.ceil((e - a) / longest)))
        edges = np.linspace(a, e, pieces + 1).round().astype(np.int64)
        for p0, p1 in zip(edges[:-1], edges[1:], strict=False):
            ids[p0:p1] = k
            k += 1
    return ids


def block_predictive_loglik(white: np.ndarray, jac: np.ndarray | None, ids: np.ndarray) -> np.ndarray:
    """Per block: the log-likelihood of its whitened residual as predicted by the model
    fitted on the other blocks (block PRESS residuals), under the model's own variance."""
    n = white.size
    nb = int(ids.max()) + 1 if n else 0
    var = max(float(np.dot(white, white)) / max(n, 1), 1e-300)
    out = np.zeros(nb)
    if jac is None or jac.size == 0:
        e_out = white
    else:
        q, r = np.linalg.qr(jac)
        keep = np.abs(np.diag(r)) > 1e-10 * max(float(np.max(np.abs(np.diag(r)))), 1e-300)
        q = q[:, keep]
        e_out = np.empty(n)
        order = np.argsort(ids, kind="stable")
        bounds = np.searchsorted(ids[order], np.arange(nb + 1))
        for b in range(nb):
            rows = order[bounds[b]:bounds[b + 1]]
            # (I − Q_B Q_Bᵀ)⁻¹ e = e + Q_B (I − Q_BᵀQ_B)⁻¹ Q_Bᵀ e (Woodbury): p × p, not |B| × |B|
            qb = q[rows]
            eb = white[rows]
            inner = np.eye(qb.shape[1]) - qb.T @ qb
            e_out[rows] = eb + qb @ np.linalg.lstsq(inner, qb.T @ eb, rcond=None)[0]
    dens = -0.5 * (math.log(2.0 * math.pi * var) + e_out**2 / var)
    np.add.at(out, ids, dens)
    return out


def cv_gain(with_effect: np.ndarray, without: np.ndarray) -> CvGain:
    """From the per-block predictive log-likelihoods of the two models."""
    g = np.asarray(with_effect) - np.asarray(without)
    b = g.size
    total = float(g.sum())
    se = float(math.sqrt(b / (b - 1) * float(np.sum((g - g.mean()) ** 2)))) if b >= 2 else math.inf
    return CvGain(total, se, b)

