"""Effects seen beside the measured axis's prediction: the other axis, the host clock,
the sequence counter, the slow wander of the bias.

Each fits an extension of the baseline's assumption on the data the effect lives in, and
is judged by the same criterion as the signal effects (criterion.py): the out-of-block
predictive log-likelihood gain over blocks of that data, above what its k parameters
gain by chance at the false-alarm rate. The in-sample likelihood ratio's p is reported
beside it, it does not decide.

- cross_axis: the other axis at rest by the baseline (it reads noise and its own
  offset) against other = k·reading (in-plane misalignment and the part's cross-axis
  sensitivity: one motion direction cannot tell them apart);
- timing: host arrival delays (t_host − board end of period) as the baseline's host
  link makes them (UART frame time + exponential latency, clocks in step) against a
  host clock that runs at another rate plus a uniform hold-back of up to L (a USB
  adapter's latency timer, bursts);
- sample_loss: the baseline loses nothing; any sequence gap is the effect (a block with a
  gap has probability 0 under the baseline: its gain is infinite — a gap is a fact);
- bias_random_walk: block means of the final residual as white noise against white
  noise plus a random walk of the bias (a local-level model, exact Kalman likelihood);
  each fold of the block means is predicted one step ahead by the filter whose
  variances were fitted without it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize, minimize_scalar
from scipy.stats import chi2

from gateway.core.diagnosis.context import USABLE_COLUMN_FRACTION, G, Prepared
from gateway.core.diagnosis.criterion import ALPHA, MIN_CV_BLOCKS, CvGain, block_ids, block_predictive_loglik, cv_gain
from gateway.core.diagnosis.host_timing import (
    BASELINE_LATENCY_MEAN_S,
    TIMING_RESOLUTION_S,
    host_delays,
    host_time_position_mm,
    judge_timing,
    predictive_logliks,
)
from gateway.core.diagnosis.reading import fit_noise_model, gaussian_loglik
from gateway.core.diagnosis.signal_interface import Compensation


@dataclass
class SideTest:
    params: dict[str, tuple[float, float]]
    loglik_before: float
    loglik_after: float
    extra_params: int
    p_value: float
    rms_before: float
    rms_after: float
    detail: str = ""
    #: unit of rms_before/after, the suffix of the gain's residual_rms_* key; None: no
    #: residual to compare (sample loss is counted, not fitted)
    rms_unit: str | None = "mps2"
    compensation: Compensation | None = None
    values: dict = field(default_factory=dict)  # for the gain computation
    #: what the effect does to a position where a user meets it (mm), when the residual
    #: share cannot say (judgement.matters); None: judged by the share and the distance
    position_mm: float | None = None
    #: the parameters the setup's and the physical ranges judge (judgement.setup_range,
    #: judgement.physical), in their units; None: none to judge
    theta: np.ndarray | None = None
    #: the out-of-block predictive gain (criterion.py) that judges it; None: no test made
    cv: CvGain | None = None

    def predictive(self, alpha: float) -> bool:
        """The one criterion (criterion.CvGain.predictive) with this test's parameters."""
        return self.cv is not None and self.cv.predictive(alpha, self.extra_params)


class SideEffect:
    name = ""
    summary = ""

    def unusable(self, prep: Prepared) -> str | None:
        return None

    def test(self, prep: Prepared, residual: np.ndarray) -> SideTest:
        raise NotImplementedError


def _lr_p(ll0: float, ll1: float, k: int, boundary: bool = False) -> float:
    stat = max(0.0, 2.0 * (ll1 - ll0))
    p = float(chi2.sf(stat, k))
    # a variance at its boundary (0) under the null: half χ²(0), half χ²(k)
    return 0.5 * p if boundary else p


class CrossAxis(SideEffect):
    name = "cross_axis"
    summary = "the motion shows on the other axis: other = k·a (misalignment + cross-axis sensitivity)"

    def unusable(self, prep):
        d = prep.data
        if d.reference != "recorded":
            return "needs the recorded reference motion"
        if d.other_mps2 is None or np.isfinite(d.other_mps2).mean() < USABLE_COLUMN_FRACTION:
            return "needs the other axis"
        if not d.other_axis_still:
            return ("the other axis has no reference, so its own motion would read as cross-talk: "
                    "looked for only when it stands still (--other-axis-still)")
        return None

    def test(self, prep, residual):
        o = prep.data.other_mps2
        ok = np.isfinite(o)
        x = prep.reading_mps2
        base = np.column_stack([np.ones(o.size), prep.drift_shape])
        noise = fit_noise_model((o - np.mean(o[ok & prep.rest]))[ok & prep.rest])

        def fit(cols):
            coef = np.linalg.lstsq(cols[ok], o[ok], rcond=None)[0]
            r = np.where(ok, o - cols @ coef, 0.0)
            w = noise.whiten(r)[ok]
            return coef, r, w

        _, r0, w0 = fit(base)
        full = np.column_stack([base, x])
        coef, r1, w1 = fit(full)
        ll0, ll1 = gaussian_loglik(w0), gaussian_loglik(w1)
        # out of block: each rest and stroke of the other axis predicted by the regression
        # fitted on the others (exact for a linear model: block PRESS residuals)
        ids = block_ids(np.flatnonzero(ok), prep.rest)

        def whitened_columns(cols):
            return np.column_stack([noise.whiten(np.where(ok, c, 0.0))[ok] for c in cols.T])

        cv = cv_gain(block_predictive_loglik(w1, whitened_columns(full), ids),
                     block_predictive_loglik(w0, whitened_columns(base), ids))
        wx = noise.whiten(np.where(ok, x - x[ok].mean(), 0.0))[ok]
        k = float(coef[2])
        k_std = math.sqrt(float(np.dot(w1, w1)) / w1.size / max(float(np.dot(wx, wx)), 1e-300))
        angle = math.degrees(math.asin(max(-1.0, min(1.0, k))))
        return SideTest(
            params={"other_axis_gain": (k, k_std), "misalignment_deg": (angle, math.degrees(k_std))},
            loglik_before=ll0, loglik_after=ll1, extra_params=1, p_value=_lr_p(ll0, ll1, 1),
            rms_before=float(np.std(r0[ok])), rms_after=float(np.std(r1[ok])),
            detail="measured on the other axis", cv=cv,
            # the axis sees a·cos α of the motion: read the path acceleration as x / cos α
            compensation=Compensation(acc_mps2=None, settings={"scale": 1.0 / math.sqrt(max(1e-6, 1.0 - k * k))}),
        )


class Timing(SideEffect):
    """Host delays are compared as a histogram of TIMING_RESOLUTION_S bins.

    A latency model with a hard lower edge is pinned by its few smallest values to
    ~μ/n (tens of ns): any µs-level offset — the board's ±1-tick sample times, a lost
    sample's period taken as its neighbour's — would then read as a timing effect. Host
    timing that matters is 0.1–10s of ms, so the likelihood is binned at 0.1 ms.
    """

    name = "timing"
    summary = "host timestamps disagree with the board's T2 clock: clock rate, latency bursts, jitter"

    def unusable(self, prep):
        if not prep.data.column_ok("t_host_s"):
            return "needs host arrival times (t_host_s)"
        return None

    def test(self, prep, residual):
        d = prep.data
        delays = host_delays(d.t_s, d.t_host_s, d.lost_before, d.period_s)
        delay, t, t_end, ok, keep = delays.delay_s, delays.t_s, delays.t_end_s, delays.finite, delays.kept
        res = TIMING_RESOLUTION_S
        # the extension with or without a clock step, judged out of block (host_timing.py),
        # at the false-alarm rate the side tests share
        verdict = judge_timing(delay, t, res, ALPHA / len(SIDE_EFFECTS))
        full = verdict.fit
        every = np.ones(t.size, dtype=bool)
        ll0, ll1 = predictive_logliks(delay, t, every, every, full, res)
        x1 = full.corrected(delay, t)
        spread = float(np.std(np.diff(d.t_host_s[ok])))
        excess0 = delay - delay.min() - full.base_mean_s
        excess1 = x1 - x1.min() - (full.hold_s / 2 + full.mean_s)
        position_mm = host_time_position_mm(x1, np.abs(d.ref_vel_mps[ok][keep]))
        # the delays' scatter beyond the baseline link's (judgement: the setup's range, and
        # whether it matters, in sample periods)
        scatter_s = math.sqrt(max(float(np.var(x1)) - BASELINE_LATENCY_MEAN_S**2, 0.0))
        step_at_s = float(t[min(full.step_index, t.size - 1)] + t_end[0] - d.t_s[0]) if full.step_s else float("nan")
        step = verdict.step_cv
        return SideTest(
            params={"clock_rate_error_ppm": (full.rate * 1e6, float("nan")),
                    "hold_back_ms": (full.hold_s * 1e3, float("nan")),
                    "latency_mean_ms": (full.mean_s * 1e3, float("nan")),
                    "clock_step_ms": (full.step_s * 1e3, float("nan")),
                    "clock_step_at_s": (step_at_s, float("nan")),
                    "arrival_interval_std_ms": (spread * 1e3, float("nan")),
                    "position_at_top_speed_mm": (position_mm, float("nan"))},
            loglik_before=ll0, loglik_after=ll1, extra_params=verdict.extra_params,
            p_value=_lr_p(ll0, ll1, verdict.extra_params),
            rms_before=float(np.sqrt(np.mean(excess0**2))), rms_after=float(np.sqrt(np.mean(excess1**2))),
            rms_unit="s",
            detail=(f"host delay against the board clock, {res * 1e3:g} ms bins; baseline latency "
                    f"mean {BASELINE_LATENCY_MEAN_S * 1e3:g} ms; a host clock step: "
                    + (f"{full.step_s * 1e3:+.1f} ms at {step_at_s:.2f} s" if full.step_s else "none")
                    + f" (out of block {step.text()})"),
            # the delays' scatter beyond the baseline link's, in sample periods (judgement.matters)
            values={"host_time": True, "host_scatter_periods": scatter_s / d.period_s},
            position_mm=position_mm,
            # the hold-back (s), the clock's rate error (fraction), the delays' scatter (s), the clock's step (s)
            theta=np.array([full.hold_s, full.rate, scatter_s, full.step_s]),
            cv=verdict.cv,
        )


class SampleLoss(SideEffect):
    name = "sample_loss"
    summary = "samples lost on the serial line (sequence gaps); the baseline loses none"

    def test(self, prep, residual):
        lost = prep.data.lost_before
        gaps = int(np.count_nonzero(lost))
        total = int(lost.sum())
        n = len(prep.data) + total
        frac = total / n
        # the baseline gives a gap probability 0: any gap makes its likelihood 0
        ll1 = (total * math.log(frac) + (n - total) * math.log1p(-frac)) if total else 0.0
        ll0 = -math.inf if total else 0.0
        return SideTest(
            params={"lost_fraction": (frac, math.sqrt(frac * (1 - frac) / n)),
                    "gaps": (float(gaps), 0.0),
                    "mean_gap_samples": ((total / gaps) if gaps else 0.0, 0.0)},
            loglik_before=ll0, loglik_after=ll1, extra_params=1, p_value=0.0 if total else 1.0,
            rms_before=0.0, rms_after=0.0, rms_unit=None, detail=f"{total} samples lost in {gaps} gaps",
            values={"lost": True},
            # a block with a gap has probability 0 under the baseline: predicted infinitely
            # better by any loss rate; without a gap there is nothing to predict
            cv=CvGain(math.inf if total else 0.0, 0.0, gaps),
        )


def local_level_terms(y: np.ndarray, dt_s, k: float, sigma: float, use: np.ndarray | None = None) -> np.ndarray:
    """Each value's one-step predictive log density under y = level + white(σ), level a
    random walk with Var step K²·dt (a Kalman filter, diffuse start: the first used value
    fixes the level and has no term).

    dt_s: one spacing, or each step's (len(y) − 1: blocks with motion between them).
    use: the values the filter updates on (default all); the others are predicted and
    skipped — how a fold is left out."""
    n = len(y)
    q = k * k * np.broadcast_to(np.asarray(dt_s, dtype=float), (max(n - 1, 0),))
    use = np.ones(n, dtype=bool) if use is None else use
    r = sigma * sigma
    out = np.zeros(n)
    level, p = None, 0.0
    for i in range(n):
        if level is not None and i > 0:
            p += q[i - 1]
        if level is None:
            if use[i]:
                level, p = float(y[i]), r
            continue
        s = p + r
        e = float(y[i]) - level
        out[i] = -0.5 * (math.log(2.0 * math.pi * s) + e * e / s)
        if use[i]:
            gain = p / s
            level += gain * e
            p *= 1.0 - gain
    return out


def local_level_loglik(y: np.ndarray, dt_s, k: float, sigma: float, use: np.ndarray | None = None) -> float:
    """Exact log-likelihood of the used values (local_level_terms)."""
    terms = local_level_terms(y, dt_s, k, sigma, use)
    return float(terms.sum() if use is None else terms[use].sum())


class BiasRandomWalk(SideEffect):
    """Block means of the residual where the axis is at rest, as white noise against white
    noise plus a random walk of the level.

    Only rest blocks: a random walk is a property of the bias, and at rest the reading is
    the bias and noise alone. In motion the residual also carries whatever the motion's
    model lacks (a tilt or a temperature term of a slightly other shape, the reading's
    timing), and block means of that wander too: a walk fitted there names the leftover
    of another effect (seen as `bias_random_walk` beside tilt and temperature on the
    independent generator). Between rest blocks the walk's variance grows with the time
    between them. A record with fewer than MIN_BLOCKS rest blocks cannot show a walk (a
    stroke record's rests are a few seconds: docs/diagnosis.md, sensor_effects.SCENARIO_FOR).
    """

    name = "bias_random_walk"
    summary = "the bias wanders as a random walk beyond the exponential drift (Allan slope +1/2)"
    # a block of 0.25 s averages the part's noise (its 50 Hz pole: 25 correlation times)
    # to white block means while a walk of the documented sizes (0.3–0.8 mg/√s) moves by
    # 0.15–0.4 mg within it; one block at least in each of the criterion's folds (the
    # local-level model's two variances need a score of them anyway)
    block_s = 0.25
    MIN_BLOCKS = MIN_CV_BLOCKS

    def unusable(self, prep):
        if not prep.rest.any():
            return "needs the axis at rest (a walk of the bias is read where nothing else moves the reading)"
        return None

    def test(self, prep, residual):
        d = prep.data
        ok = np.isfinite(residual) & prep.rest
        idx = np.floor((d.t_s - d.t_s[0]) / self.block_s).astype(np.int64)
        cnt = np.bincount(idx[ok], minlength=idx[-1] + 1)
        tot = np.bincount(idx[ok], weights=residual[ok], minlength=idx[-1] + 1)
        # a block counts when at least half of it is at rest and usable
        full = np.flatnonzero(cnt >= max(3, int(0.5 * self.block_s / d.period_s)))
        y = tot[full] / cnt[full]
        if y.size < self.MIN_BLOCKS:
            return SideTest({}, 0.0, 0.0, 1, 1.0, 0.0, 0.0,
                            detail=f"{y.size} blocks of {self.block_s:g} s at rest: too few to see a walk "
                                   f"(needs {self.MIN_BLOCKS})")
        sigma0 = float(np.std(y))
        dt = np.diff(full) * self.block_s

        def nll(p):
            return -local_level_loglik(y, dt, math.exp(p[0]), math.exp(p[1]))

        # the null on the same footing (same diffuse start, same terms): K = 0, σ free
        null = minimize_scalar(lambda ls: -local_level_loglik(y, dt, 0.0, math.exp(ls)),
                               bounds=(math.log(sigma0) - 3, math.log(sigma0) + 3), method="bounded")
        ll0 = -float(null.fun)

        starts = [(math.log(max(sigma0 * f / math.sqrt(self.block_s), 1e-9)), math.log(sigma0 * g))
                  for f in (0.05, 0.3, 1.0) for g in (0.5, 1.0)]
        best = min((minimize(nll, s0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3})
                    for s0 in starts), key=lambda r: r.fun)
        k, sigma = math.exp(best.x[0]), math.exp(best.x[1])
        ll1 = max(-float(best.fun), ll0)
        cv = self._out_of_fold(y, dt, best.x, float(null.x))
        # σ of log K from the curvature of the profile likelihood in log K
        h = 0.05
        f0 = nll(best.x)
        curv = (nll([best.x[0] + h, best.x[1]]) - 2 * f0 + nll([best.x[0] - h, best.x[1]])) / (h * h)
        k_std = k / math.sqrt(curv) if curv > 0 else float("nan")
        return SideTest(
            params={"random_walk_ug_per_rts": (k / G * 1e6, k_std / G * 1e6),
                    "white_block_mg": (sigma / G * 1e3, float("nan"))},
            loglik_before=ll0, loglik_after=ll1, extra_params=1,
            p_value=_lr_p(ll0, ll1, 1, boundary=True),
            rms_before=sigma0, rms_after=sigma,
            detail=f"means of {y.size} blocks of {self.block_s:g} s of the residual at rest",
            compensation=Compensation(settings={"bias_random_walk_mps2_per_rts": k}),
            values={"k_mps2_per_rts": k}, cv=cv,
        )

    @staticmethod
    def _out_of_fold(y: np.ndarray, dt: np.ndarray, walk_start, null_start: float) -> CvGain:
        """MIN_CV_BLOCKS contiguous folds of the block means: each predicted one step ahead
        by the walk and by white noise, both with variances fitted without it."""
        folds = np.minimum((np.arange(y.size) * MIN_CV_BLOCKS) // y.size, MIN_CV_BLOCKS - 1)
        with_walk, without = np.zeros(MIN_CV_BLOCKS), np.zeros(MIN_CV_BLOCKS)
        for f in range(MIN_CV_BLOCKS):
            use, held = folds != f, folds == f
            walk = minimize(lambda p, u=use: -local_level_loglik(y, dt, math.exp(p[0]), math.exp(p[1]), u),
                            walk_start, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3})
            null = minimize_scalar(lambda ls, u=use: -local_level_loglik(y, dt, 0.0, math.exp(ls), u),
                                   bounds=(null_start - 3, null_start + 3), method="bounded")
            with_walk[f] = local_level_terms(y, dt, math.exp(walk.x[0]), math.exp(walk.x[1]))[held].sum()
            without[f] = local_level_terms(y, dt, 0.0, math.exp(null.x))[held].sum()
        return cv_gain(with_walk, without)


SIDE_EFFECTS: tuple[SideEffect, ...] = (CrossAxis(), Timing(), SampleLoss(), BiasRandomWalk())
