"""The `timing` side effect: host arrival times against the board's clock.

What a host stamping samples on arrival sees through a serial link (the physics the
own simulator makes, gateway/core/sensor_effects.TimingTerm):

- the baseline link: each frame is on the host after its UART time plus an
  exponential latency (mean BASELINE_LATENCY_MEAN_S); clocks in step;
- a buffering USB-serial adapter (FTDI AN232B-04; a CP210x alike): the chip sends what
  it holds when a 62-byte packet is full or when its latency timer (1–255 ms) expires,
  and the host stamps every frame of one packet at once. A frame waits between 0 and
  the hold-back L (the timer, or a packet's fill time when shorter): U(0, L) as the
  frames meet the flushes at all phases;
- the host clock: off in rate (a crystal's tens of ppm; NTP slewing an offset at up to
  500 ppm) and stepped — ntpd steps an offset beyond 128 ms at once, chrony's makestep,
  PTP or a person setting the clock step smaller ones. A step back makes arrival times
  go backwards.

So the host delay of sample k (its host time less the end of its period on the board's
clock) is, under the extension,

    delay_k = c + rate·t_k + step·[k ≥ k_step] + U(0, L) + Exp(μ)

against the baseline's c + Exp(μ). The step is one more pair of parameters (its size
and where), kept only when it predicts the delays better out of block by more than two
useless parameters gain by chance (the one criterion, criterion.CvGain) — a record
without a step reports none. Fitting: the rate and the step from the delays' lower
envelope (each block's 5th percentile: the frames that waited least), the step's place
refined to the sample by the likelihood, then L and μ by binned maximum likelihood.

Judged like every candidate (criterion.py): MIN_CV_BLOCKS contiguous stretches, each
predicted by both models fitted on the others. A step fitted on the others lies
somewhere in the stretch left out when that stretch holds it: its place there is
unknown, so the stretch's predictive likelihood averages over every place in it (a
uniform prior: the exact predictive density of a change point not seen).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize, minimize_scalar
from scipy.special import logsumexp

from gateway.core.diagnosis.criterion import MIN_CV_BLOCKS, CvGain, cv_gain

# The baseline host link (sensor_model.HostLinkParams): exponential latency, mean 0.2 ms.
BASELINE_LATENCY_MEAN_S = 0.2e-3
# The bin width of the timing test (see Timing)
TIMING_RESOLUTION_S = 1e-4
# a stretch between sequence gaps gives the delay's lower edge by its smallest value: of n
# exponential latencies the smallest lies μ/n above the edge, 20 samples put it within
# 5 % of the baseline's 0.2 ms (10 µs, a tenth of a bin)
MIN_EDGE_STRETCH = 20
# the extension's parameters beyond the baseline's: rate, hold-back, latency; a clock
# step adds its size and its place
TIMING_PARAMS = 3
STEP_PARAMS = 2
# the lower envelope's blocks: at least ENVELOPE_MIN_DELAYS delays each (every packet's
# last frame waits ~0: a block holding a few packets reaches the edge), at most
# ENVELOPE_MAX_BLOCKS; a step is looked for with ENVELOPE_STEP_MARGIN blocks on each side
# (a level from one block is its 5th percentile's noise)
ENVELOPE_MIN_DELAYS = 50
ENVELOPE_MAX_BLOCKS = 50
ENVELOPE_STEP_MARGIN = 2
# the step's size is refined by the likelihood within this many bins of the envelope's
# (a search range, not a threshold: the envelope's error is a few tenths of a ms)
STEP_SEARCH_BINS = 10


def delay_cdf(x, hold_s: float, mean_s: float):
    """CDF of U(0, L) + Exp(μ) (L = 0: the exponential alone)."""
    x = np.maximum(np.asarray(x, dtype=float), 0.0)
    if hold_s <= 0.0:
        return -np.expm1(-x / mean_s)
    below = np.minimum(x, hold_s)
    # ∫0^x (1 − e^(−u/μ))/L du for x ≤ L; beyond L the exponential tail of the sum
    inside = (below + mean_s * np.expm1(-below / mean_s)) / hold_s
    # (x − L clipped at 0: np.where evaluates both branches, and e^(−(x−L)/μ) for x ≪ L overflowed)
    past = np.maximum(x - hold_s, 0.0)
    beyond = np.where(x > hold_s, mean_s * -np.expm1(-hold_s / mean_s) * -np.expm1(-past / mean_s) / hold_s, 0.0)
    return inside + beyond


def binned_loglik(counts: np.ndarray, edges: np.ndarray, hold_s: float, mean_s: float) -> float:
    """Multinomial log-likelihood of a histogram (last bin open to +∞)."""
    cdf = delay_cdf(edges, hold_s, mean_s)
    p = np.diff(np.append(cdf, 1.0))
    return float(np.sum(counts * np.log(np.maximum(p, 1e-300))))


def sample_logp(x: np.ndarray, origin: float, hold_s: float, mean_s: float, res: float) -> np.ndarray:
    """Each value's log-probability of its TIMING_RESOLUTION_S bin above the model's lower
    edge `origin` (a value below the edge counts in the first bin)."""
    k = np.maximum(np.floor((x - origin) / res), 0.0)
    p = delay_cdf((k + 1.0) * res, hold_s, mean_s) - delay_cdf(k * res, hold_s, mean_s)
    return np.log(np.maximum(p, 1e-300))


def host_time_position_mm(delay_s: np.ndarray, speed_mps: np.ndarray) -> float:
    """How far a position stamped with the host's arrival time lies from where the axis
    was, at the record's top speed: top speed × the delay's scatter beyond what the
    baseline link gives (Exp(μ) has σ = μ), in mm rms.

    Why not the residual share: the baseline and the extension are both distributions of
    the same delays around their own means, so the spread left "unexplained" is the same
    under both (a latency timer's U(0, L) has σ = L/√12 either way) and the share is ~0
    for any L. What a latency timer costs a user is the scatter itself: a gateway stamping
    (or a logger timing) samples on arrival misplaces each by v·δt. The top speed is the
    99th percentile of |v| (one spike of a differentiated reference does not set it)."""
    if delay_s.size < 2 or speed_mps.size == 0:
        return 0.0
    excess_var = float(np.var(delay_s)) - BASELINE_LATENCY_MEAN_S**2
    top_speed = float(np.quantile(speed_mps[np.isfinite(speed_mps)], 0.99)) if np.isfinite(speed_mps).any() else 0.0
    return top_speed * math.sqrt(max(excess_var, 0.0)) * 1e3


@dataclass(frozen=True)
class HostDelays:
    """The host delays a recording's clocks give, as the timing test reads them."""

    delay_s: np.ndarray  # host time less the end of the sample's period, from its stretch's edge
    t_s: np.ndarray  # the board's time of each, from the first
    t_end_s: np.ndarray  # the end of each finite row's period (board clock)
    finite: np.ndarray  # rows with a host time
    kept: np.ndarray  # of those, the ones in a stretch long enough for its edge


def host_delays(t_s: np.ndarray, t_host_s: np.ndarray, lost_before: np.ndarray, period_s: float) -> HostDelays:
    """Each sample's host delay against the board's clock. After a gap the board's time
    steps by up to a tick per lost sample: the delay's lower edge is taken per stretch
    between gaps, and stretches shorter than MIN_EDGE_STRETCH are dropped."""
    ok = np.isfinite(t_host_s)
    t_end = t_s[ok] + period_s  # the sample is sent when its period ends
    delay = t_host_s[ok] - t_end
    stretch = np.cumsum(np.asarray(lost_before) > 0)[ok]
    sizes = np.bincount(stretch)
    keep = sizes[stretch] >= MIN_EDGE_STRETCH
    edge = np.full(sizes.size, np.inf)
    np.minimum.at(edge, stretch[keep], delay[keep])
    return HostDelays((delay - edge[stretch])[keep], (t_end - t_end[0])[keep], t_end, ok, keep)


@dataclass(frozen=True)
class TimingFit:
    """Both host-delay models as fitted on some of the delays."""

    rate: float  # the host clock's rate error against the board's (fraction)
    hold_s: float  # the extension's uniform hold-back L
    mean_s: float  # the extension's exponential latency μ
    base_mean_s: float  # the baseline's exponential latency μ
    step_s: float = 0.0  # the host clock's step (0: none)
    step_index: int = 0  # the first delay after the step (index into the record's delays)
    #: where the envelope puts the step: somewhere before one of window_lo … window_hi
    #: (the step's place is a parameter known to within this window, module docstring)
    window_lo: int = 0
    window_hi: int = 0

    def corrected(self, delay: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The delays less the clock's line and step: what U(0, L) + Exp(μ) describes."""
        x = delay - self.rate * t
        if self.step_s:
            x = x.copy()
            x[self.step_index:] -= self.step_s
        return x

    def with_step_at(self, k: int) -> TimingFit:
        return replace(self, step_index=k)


def fit_timing(delay: np.ndarray, t: np.ndarray, use: np.ndarray, res: float, with_step: bool,
               start: TimingFit | None = None) -> TimingFit:
    """Both host-delay models fitted on the delays `use` (module docstring)."""
    idx = np.flatnonzero(use)
    d, tt = delay[idx], t[idx]
    rate, step, lo, hi = _envelope(d, tt, idx, with_step, res)
    c0, e0 = _delay_histogram(d, res)
    mu0 = max(float(np.mean(d - d.min())), res / 10)
    bounds = (math.log(mu0) - 4, math.log(mu0) + 2)
    base = minimize_scalar(lambda lm: -binned_loglik(c0, e0, 0.0, math.exp(lm)), bounds=bounds, method="bounded")
    fit = TimingFit(rate, 0.0, mu0, math.exp(base.x), step, hi + 1, lo, hi)
    # L and μ first from the delays whose side of a step is known (the window left out),
    # so that the step's place is then found by a model its uncertain delays have not widened
    known = idx[(idx < lo) | (idx > hi)] if step else idx
    hold, mu = _hold_and_latency(fit.corrected(delay, t)[known], res, bounds, start)
    fit = replace(fit, hold_s=hold, mean_s=mu)
    if step:
        # the step's place to the sample: the most likely split of the window's used delays
        origin = float(np.min(fit.corrected(delay, t)[known]))
        places, ll_used, _ = _step_places(delay, t, use, np.zeros_like(use), fit, origin, res)
        fit = fit.with_step_at(int(places[int(np.argmax(ll_used))]))
        # the step's size by the likelihood, near the envelope's (whose blocks' 5th
        # percentiles move with the phase at which the frames meet the flushes)
        fit = replace(fit, step_s=_step_size(delay, t, idx, fit, res))
        if abs(fit.step_s) < res:  # below the resolution once sized: none (as in _envelope)
            fit = replace(fit, step_s=0.0, step_index=0, window_lo=0, window_hi=0)
        hold, mu = _hold_and_latency(fit.corrected(delay, t)[idx], res, bounds, fit)
        fit = replace(fit, hold_s=hold, mean_s=mu)
    return fit


def _step_size(delay: np.ndarray, t: np.ndarray, idx: np.ndarray, fit: TimingFit, res: float) -> float:
    """The step that makes the used delays most likely under the fit's L and μ, searched
    within STEP_SEARCH_BINS bins of the fit's."""
    def nll(step):
        c, e = _delay_histogram(replace(fit, step_s=step).corrected(delay, t)[idx], res)
        return -binned_loglik(c, e, fit.hold_s, fit.mean_s)

    span = STEP_SEARCH_BINS * res
    best = minimize_scalar(nll, bounds=(fit.step_s - span, fit.step_s + span), method="bounded",
                           options={"xatol": res / 100})
    return float(best.x) if best.fun < nll(fit.step_s) else fit.step_s


def _envelope(d: np.ndarray, tt: np.ndarray, idx: np.ndarray, with_step: bool,
              res: float = TIMING_RESOLUTION_S) -> tuple[float, float, int, int]:
    """The clock's rate and step from the delays' lower envelope: each block's 5th
    percentile (the edge, not moved by one early sample), a line, or a line and a step
    between two blocks (the one of least squares). Returns rate, step and the window of
    the record's delays the step lies in: the two blocks around the change (a block's 5th
    percentile is its lower side's) and one more on each side. A step smaller than the
    test's resolution `res` is none: the binned likelihood cannot resolve it (a few µs
    moved across the lower edge's bin reads as a gain: seen on clean records)."""
    blocks = np.array_split(np.arange(tt.size), max(2, min(ENVELOPE_MAX_BLOCKS, tt.size // ENVELOPE_MIN_DELAYS)))
    bt = np.array([float(np.median(tt[b])) for b in blocks])
    bd = np.array([float(np.quantile(d[b], 0.05)) for b in blocks])
    if bt.size < 3:
        return 0.0, 0.0, 0, 0
    line = np.column_stack([np.ones(bt.size), bt - bt[0]])
    coef, rss = _lstsq(line, bd)
    rate, step, lo, hi = float(coef[1]), 0.0, 0, 0
    if with_step and bt.size >= 2 * ENVELOPE_STEP_MARGIN + 1:
        best = math.inf
        for j in range(ENVELOPE_STEP_MARGIN, bt.size - ENVELOPE_STEP_MARGIN + 1):
            c, r = _lstsq(np.column_stack([line, np.arange(bt.size) >= j]), bd)
            if r < best:
                best, rate, step = r, float(c[1]), float(c[2])
                lo, hi = int(idx[blocks[max(j - 2, 0)][0]]), int(idx[blocks[min(j + 1, bt.size - 1)][-1]])
        if abs(step) < res:
            return float(coef[1]), 0.0, 0, 0
    return rate, step, lo, hi


def _step_places(delay: np.ndarray, t: np.ndarray, use: np.ndarray, held: np.ndarray, fit: TimingFit,
                 origin: float, res: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each place the step can have in the window (before window_lo, …, after
    window_hi): the log-likelihood of the window's used delays and of its held ones."""
    w = np.arange(fit.window_lo, fit.window_hi + 1)
    raw = delay[w] - fit.rate * t[w]
    lp_before = sample_logp(raw, origin, fit.hold_s, fit.mean_s, res)
    lp_after = sample_logp(raw - fit.step_s, origin, fit.hold_s, fit.mean_s, res)

    def split(mask):
        # the step after the first p of the window, p = 0 … n
        b, a = np.where(mask[w], lp_before, 0.0), np.where(mask[w], lp_after, 0.0)
        return np.concatenate([[0.0], np.cumsum(b)]) + np.concatenate([np.cumsum(a[::-1])[::-1], [0.0]])

    return np.append(w, fit.window_hi + 1), split(use), split(held)


def _lstsq(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    coef = np.linalg.lstsq(a, b, rcond=None)[0]
    return coef, float(np.sum((b - a @ coef) ** 2))


def _hold_and_latency(x: np.ndarray, res: float, bounds: tuple[float, float],
                      start: TimingFit | None) -> tuple[float, float]:
    """U(0, L) + Exp(μ) by binned maximum likelihood on the corrected delays x; nested:
    never below the exponential alone (L = 0)."""
    c1, e1 = _delay_histogram(x, res)
    span = float(np.ptp(x))
    mu0 = max(float(np.mean(x - x.min())), res / 10)
    if start is None or start.hold_s <= 0.0:
        starts = [(math.log(max(f * span, res / 10)), math.log(max(g * mu0, res / 10)))
                  for f in (0.05, 0.5, 0.9) for g in (0.1, 1.0)]
    else:  # a fold: from the whole record's fit
        starts = [(math.log(max(start.hold_s, res / 10)), math.log(max(start.mean_s, res / 10)))]
    best = min((minimize(lambda p: -binned_loglik(c1, e1, math.exp(p[0]), math.exp(p[1])), s0,
                         method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 400})
                for s0 in starts), key=lambda r: r.fun)
    hold, mu = (math.exp(v) for v in best.x)
    exp_only = minimize_scalar(lambda lm: -binned_loglik(c1, e1, 0.0, math.exp(lm)), bounds=bounds, method="bounded")
    if -float(exp_only.fun) > -float(best.fun):
        hold, mu = 0.0, math.exp(exp_only.x)
    return hold, mu


def _delay_histogram(x: np.ndarray, res: float):
    """Counts of x − min(x) in bins of res (the last open), and the bins' lower edges."""
    x = x - x.min()
    edges = np.arange(0.0, float(x.max()) + res, res)
    counts = np.bincount(np.minimum((x / res).astype(np.int64), edges.size - 1), minlength=edges.size)
    return counts, edges


def predictive_logliks(delay: np.ndarray, t: np.ndarray, use: np.ndarray, held: np.ndarray, fit: TimingFit,
                       res: float) -> tuple[float, float]:
    """Log-likelihoods of the delays `held` under the baseline and the extension fitted
    on the delays `use` (all of them: in sample, the step where the fit put it); each
    model's lower edge is where its fit put it (the used delays' lowest). Held out, the
    step's place is the window's: the held delays there are predicted by every place,
    each weighted by how well it explains the used ones (the exact predictive density
    of a change point under a uniform prior over the window)."""
    base_origin = float(np.min(delay[use]))
    base = float(sample_logp(delay[held], base_origin, 0.0, fit.base_mean_s, res).sum())
    x = fit.corrected(delay, t)
    origin = float(np.min(x[use]))
    lp = sample_logp(x, origin, fit.hold_s, fit.mean_s, res)
    in_sample = bool(np.all(use[held]))
    window = np.zeros(delay.size, dtype=bool)
    window[fit.window_lo:fit.window_hi + 1] = True
    if not fit.step_s or in_sample or not (held & window).any():
        return base, float(lp[held].sum())
    _, ll_used, ll_held = _step_places(delay, t, use, held, fit, origin, res)
    ext = float(lp[held & ~window].sum()) + float(logsumexp(ll_used + ll_held) - logsumexp(ll_used))
    return base, ext


@dataclass(frozen=True)
class TimingVerdict:
    fit: TimingFit  # on the whole record
    cv: CvGain  # the extension against the baseline, out of block
    step_cv: CvGain  # the step against the extension without it, out of block
    extra_params: int


def judge_timing(delay: np.ndarray, t: np.ndarray, res: float, alpha: float) -> TimingVerdict:
    """The extension with and without a clock step, each stretch predicted out of block;
    the step kept when it predicts better by more than its STEP_PARAMS gain by chance."""
    every = np.ones(t.size, dtype=bool)
    fold = np.minimum((np.arange(t.size) * MIN_CV_BLOCKS) // max(t.size, 1), MIN_CV_BLOCKS - 1)
    fits = {s: fit_timing(delay, t, every, res, with_step=s) for s in (False, True)}
    base, ext = np.zeros(MIN_CV_BLOCKS), {s: np.zeros(MIN_CV_BLOCKS) for s in (False, True)}
    for f in range(MIN_CV_BLOCKS):
        use, held = fold != f, fold == f
        for s in (False, True):
            out = fit_timing(delay, t, use, res, with_step=s, start=fits[s])
            base[f], ext[s][f] = predictive_logliks(delay, t, use, held, out, res)
    step_cv = cv_gain(ext[True], ext[False])
    # (a record whose own fit finds no step resolved has none, whatever its folds found)
    stepped = fits[True].step_s != 0.0 and step_cv.predictive(alpha, STEP_PARAMS)
    return TimingVerdict(fits[stepped], cv_gain(ext[stepped], base), step_cv,
                         TIMING_PARAMS + (STEP_PARAMS if stepped else 0))

