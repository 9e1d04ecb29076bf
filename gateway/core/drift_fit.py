"""Identify the zero-drift model from a standstill and judge it the way the paper does.

The paper (Lee & Park, fig. 1) fits ε(t) = C1·(1 − e^(−t/T)) + C2 to a 12-hour
standstill and calls the model adequate when what remains is white. Here:

- the fit is scipy.optimize.curve_fit on block means (1 s by default): 21.6 M samples
  become 43 200 points, and a block mean is far beyond the sensor's 3 ms noise
  correlation, so its residual can be white if the model is right;
- parameter standard deviations come from the fit's covariance (scaled by the residual
  variance: curve_fit's absolute_sigma=False);
- whiteness: Ljung–Box on the block residual (numpy + the χ² tail as scipy.special.gammaincc). The full-rate
  residual is never white — the sensor's own CX filter colours it (lag-1 ≈ 0.5) — so
  whiteness is judged at the block rate, and the full-rate lag-1 autocorrelation is
  reported beside it;
- Allan deviation (overlapping) of the full-rate residual, with the noise terms read
  from the slopes −1/2 (white noise), 0 (bias instability), +1/2 (rate random walk).

Conventions (stated once, used by estimator_settings):
    white noise: one-sided density N as data sheets quote it (g/√Hz): σ_A(τ) = N/√(2τ);
    bias instability B: the flat minimum σ_A = 0.664·B (IEEE Std 952 flicker floor);
    rate random walk K (g/√s): the bias is a random walk with Var(b(t)) = K²·t, and
    σ_A(τ) = K·√(τ/3).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from gateway.core.chi2 import chi2_sf
from gateway.core.drift_model import DriftModel, drift_g

FLICKER_FLOOR_FACTOR = 0.664  # σ_A at the flat minimum = 0.664·B (IEEE Std 952, 1/f noise)
SLOPE_TOLERANCE = 0.15  # a log-log slope within ±0.15 of −1/2, 0, +1/2 counts as that term


@dataclass(frozen=True)
class LjungBox:
    statistic: float
    lags: int
    p_value: float
    n: int

    def white(self, alpha: float = 0.05) -> bool:
        return self.p_value > alpha


@dataclass(frozen=True)
class AllanDeviation:
    tau_s: np.ndarray
    adev: np.ndarray  # same unit as the input signal


@dataclass(frozen=True)
class NoiseTerms:
    """Noise terms read from an Allan deviation; None where the record does not show the slope."""

    white_density_per_rthz: float | None  # N, one-sided (data-sheet convention)
    bias_instability: float | None  # B
    bias_instability_tau_s: float | None
    rate_random_walk_per_rts: float | None  # K
    # The random walk the long-τ end of the curve allows at most: max over τ ≥ τ(min) of
    # σ_A·√(3/τ). When no +1/2 slope is resolved this bounds how fast the bias may wander.
    random_walk_bound_per_rts: float


@dataclass(frozen=True)
class FittedDrift:
    """What the estimator takes from a drift fit (adxlgw fit-drift --model-out writes it)."""

    model: DriftModel
    white_density_g_per_rthz: float | None
    random_walk_g_per_rts: float  # the resolved rate random walk, else the record's bound
    random_walk_resolved: bool

    def to_dict(self) -> dict:
        return {
            "c1_g": self.model.c1_g,
            "c2_g": self.model.c2_g,
            "time_constant_s": self.model.time_constant_s,
            "white_density_g_per_rthz": self.white_density_g_per_rthz,
            "random_walk_g_per_rts": self.random_walk_g_per_rts,
            "random_walk_resolved": self.random_walk_resolved,
        }

    @classmethod
    def from_dict(cls, d: dict) -> FittedDrift:
        """Raises KeyError/TypeError/ValueError on a malformed dict (the caller names the file)."""
        white = d.get("white_density_g_per_rthz")
        return cls(
            model=DriftModel(c1_g=float(d["c1_g"]), c2_g=float(d["c2_g"]),
                             time_constant_s=float(d["time_constant_s"])),
            white_density_g_per_rthz=None if white is None else float(white),
            random_walk_g_per_rts=float(d["random_walk_g_per_rts"]),
            random_walk_resolved=bool(d.get("random_walk_resolved", False)),
        )


@dataclass(frozen=True)
class DriftFit:
    model: DriftModel
    c1_std_g: float
    c2_std_g: float
    time_constant_std_s: float
    covariance: np.ndarray  # of (C1 [g], C2 [g], T [s])
    block_s: float
    block_t_s: np.ndarray
    block_mean_g: np.ndarray
    block_residual_g: np.ndarray
    residual_rms_g: float  # full rate
    full_rate_lag1: float  # full-rate residual's lag-1 autocorrelation (sensor filter colour)
    whiteness: LjungBox
    acf: np.ndarray  # block residual autocorrelation, lags 0..whiteness.lags
    allan: AllanDeviation
    noise: NoiseTerms
    start_t_s: float = 0.0  # the record's first sample time: the model's t = 0

    def fitted(self) -> FittedDrift:
        rrw = self.noise.rate_random_walk_per_rts
        return FittedDrift(
            model=self.model,
            white_density_g_per_rthz=self.noise.white_density_per_rthz,
            random_walk_g_per_rts=rrw if rrw is not None else self.noise.random_walk_bound_per_rts,
            random_walk_resolved=rrw is not None,
        )


def autocorrelation(x, max_lag: int) -> np.ndarray:
    """Sample autocorrelation ρ_0..ρ_max_lag (biased estimator, as Ljung–Box uses it)."""
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    denom = float(np.dot(x, x))
    if denom == 0.0:
        return np.concatenate([[1.0], np.zeros(max_lag)])
    return np.array([1.0] + [float(np.dot(x[:-k], x[k:])) / denom for k in range(1, max_lag + 1)])


def ljung_box(x, lags: int | None = None) -> LjungBox:
    """Q = n(n+2)·Σ ρ_k²/(n−k), k = 1..h; under whiteness Q ~ χ²(h)."""
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 10:
        raise ValueError(f"Ljung–Box needs at least 10 values, got {n}")
    h = lags if lags is not None else min(20, n // 5)
    rho = autocorrelation(x, h)[1:]
    q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, h + 1))))
    # chi2.sf(q, h), without scipy (the daemon imports this module: gateway/core/chi2.py)
    return LjungBox(statistic=q, lags=h, p_value=chi2_sf(q, h), n=n)


def octave_taus(n: int, max_fraction: float = 0.25) -> np.ndarray:
    """Cluster sizes 1, 2, 4, … up to max_fraction of the record."""
    top = max(1, int(n * max_fraction))
    return 2 ** np.arange(int(math.floor(math.log2(top))) + 1)


class SeriesStore(Protocol):
    """Where a long series waits between passes: appended in chunks, read back by range
    (an in-memory one here; gateway/offline/drift_scratch.py keeps it in a file)."""

    def append(self, values: np.ndarray) -> None: ...

    def read(self, start: int, count: int) -> np.ndarray: ...


class ArrayStore:
    """A SeriesStore in memory."""

    def __init__(self) -> None:
        self._parts: list[np.ndarray] = []
        self._joined: np.ndarray | None = None

    def append(self, values: np.ndarray) -> None:
        self._parts.append(np.asarray(values, dtype=float))
        self._joined = None

    def read(self, start: int, count: int) -> np.ndarray:
        if self._joined is None:
            self._joined = np.concatenate(self._parts) if self._parts else np.empty(0)
            self._parts = [self._joined]
        return self._joined[start:start + count]


#: the Allan sums and the residual's passes work on blocks of this many samples: memory
#: follows the block, not the record (the streamed fit-drift: ≤ 400 MB whatever the file)
BLOCK_SAMPLES = 1 << 20


def allan_deviation(x, period_s: float, m=None) -> AllanDeviation:
    """Overlapping Allan deviation of a rate-like signal x sampled every period_s.

    σ²(τ) = Σ (θ(k+2m) − 2θ(k+m) + θ(k))² / (2τ²(N−2m)), θ = cumulative sum · period,
    τ = m·period (IEEE Std 952 / Riley, NIST SP 1065).
    """
    x = np.asarray(x, dtype=float)
    if x.size < 4:
        raise ValueError("Allan deviation needs at least 4 samples")
    theta = ArrayStore()
    theta.append(np.concatenate([[0.0], np.cumsum(x - x.mean())]) * period_s)
    return allan_deviation_of_phase(theta, x.size, period_s, m)


def allan_deviation_of_phase(theta: SeriesStore, n: int, period_s: float, m=None) -> AllanDeviation:
    """allan_deviation from θ (n + 1 values, θ(0) = 0) held in `theta`, summed block by block."""
    m = octave_taus(n) if m is None else np.asarray(m, dtype=np.int64)
    out = np.empty(m.size)
    for i, mi in enumerate(int(v) for v in m):
        count = n + 1 - 2 * mi  # the d values: k = 0 … n − 2m
        total = 0.0
        for start in range(0, count, BLOCK_SAMPLES):
            k = min(BLOCK_SAMPLES, count - start)
            d = theta.read(start + 2 * mi, k) - 2.0 * theta.read(start + mi, k) + theta.read(start, k)
            total += float(np.dot(d, d))
        tau = mi * period_s
        out[i] = math.sqrt(total / (2.0 * tau * tau * count))
    return AllanDeviation(tau_s=m * period_s, adev=out)


def noise_terms(allan: AllanDeviation, min_tau_s: float = 0.0, record_s: float | None = None) -> NoiseTerms:
    """Read N, B, K off the slopes −1/2, 0, +1/2 of log σ_A against log τ.

    Each term's value is the median over the points whose local slope (mean of the
    slopes on either side) lies within ±SLOPE_TOLERANCE of its own; taus below
    min_tau_s (where the sensor's anti-alias filter flattens the curve) are ignored.
    """
    keep = (allan.tau_s >= min_tau_s) & (allan.adev > 0)
    if record_s is not None:
        # a slope is read only where ≥ 16 clusters fit in the record (σ_A to ~20 %); the
        # last octaves of a white record wobble enough to fake a flat minimum
        keep &= allan.tau_s <= record_s / 16.0
    tau, adev = allan.tau_s[keep], allan.adev[keep]
    if tau.size < 2:
        raise ValueError("too few Allan points to read noise terms from")
    seg = np.diff(np.log(adev)) / np.diff(np.log(tau))
    slope = np.empty(tau.size)
    slope[0], slope[-1] = seg[0], seg[-1]
    slope[1:-1] = 0.5 * (seg[:-1] + seg[1:])

    def near(target):
        return np.abs(slope - target) <= SLOPE_TOLERANCE

    white = near(-0.5)
    n_white = float(np.median(adev[white] * np.sqrt(2.0 * tau[white]))) if white.any() else None
    i_min = int(np.argmin(adev))
    flat = near(0.0)
    if flat[i_min] and 0 < i_min < tau.size - 1:
        b, b_tau = float(adev[i_min] / FLICKER_FLOOR_FACTOR), float(tau[i_min])
    else:
        b, b_tau = None, None
    rising = near(0.5) & (np.arange(tau.size) > i_min)
    k = float(np.median(adev[rising] * np.sqrt(3.0 / tau[rising]))) if rising.any() else None
    # the bound uses every point past the minimum, the wobbly long-τ ones included
    all_tau = allan.tau_s[(allan.tau_s >= tau[i_min]) & (allan.adev > 0)]
    all_adev = allan.adev[(allan.tau_s >= tau[i_min]) & (allan.adev > 0)]
    bound = float(np.max(all_adev * np.sqrt(3.0 / all_tau)))
    return NoiseTerms(
        white_density_per_rthz=n_white,
        bias_instability=b,
        bias_instability_tau_s=b_tau,
        rate_random_walk_per_rts=k,
        random_walk_bound_per_rts=bound,
    )


def _drift_curve(t, c1, c2, time_constant):
    return c1 * -np.expm1(-t / time_constant) + c2


def block_means(t_s, x, block_s: float):
    """Means of consecutive blocks of block_s seconds (NaN samples skipped; empty blocks dropped)."""
    sums = RecordSums(block_s)
    sums.add(np.asarray(t_s, dtype=float), np.asarray(x, dtype=float))
    return sums.block_means()


@dataclass
class RecordSums:
    """What the fit's first pass keeps of a record given chunk by chunk: its ends, the
    per-block sums (one pair per block: 43 200 for 12 h of 1 s blocks) and the sample
    periods seen with how often (a clocked record has few distinct ones), so that the
    median period is exact without the record in memory."""

    block_s: float
    n: int = 0
    usable: int = 0
    t_first_s: float = math.nan
    t_last_s: float = math.nan
    block_count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    block_total: np.ndarray = field(default_factory=lambda: np.zeros(0))
    periods: dict[float, int] = field(default_factory=dict)

    def add(self, t: np.ndarray, x: np.ndarray) -> None:
        if t.size != x.size:
            raise ValueError("t_s and acc_g differ in length")
        if not t.size:
            return
        steps = np.diff(t) if self.n == 0 else np.diff(np.concatenate([[self.t_last_s], t]))
        if self.n == 0:
            self.t_first_s = float(t[0])
        values, counts = np.unique(steps, return_counts=True)
        for v, c in zip(values.tolist(), counts.tolist(), strict=True):
            self.periods[v] = self.periods.get(v, 0) + c
        self.n += t.size
        self.t_last_s = float(t[-1])
        idx = np.floor((t - self.t_first_s) / self.block_s).astype(np.int64)
        good = np.isfinite(x)
        self.usable += int(good.sum())
        size = max(self.block_count.size, int(idx[-1]) + 1)
        self.block_count = _grown(self.block_count, size) + np.bincount(idx[good], minlength=size)
        self.block_total = _grown(self.block_total, size) + np.bincount(idx[good], weights=x[good], minlength=size)

    def median_period_s(self) -> float:
        """np.median of the sample periods, from their counts."""
        values = np.array(sorted(self.periods))
        ends = np.cumsum([self.periods[v] for v in values])
        total = int(ends[-1])
        lo, hi = (total - 1) // 2, total // 2
        pick = np.searchsorted(ends, [lo, hi], side="right")
        return float(np.mean(values[pick]))

    def block_means(self) -> tuple[np.ndarray, np.ndarray]:
        centre = self.t_first_s + (np.arange(self.block_count.size) + 0.5) * self.block_s
        full = self.block_count > 0
        return centre[full], self.block_total[full] / self.block_count[full]


def _grown(a: np.ndarray, size: int) -> np.ndarray:
    return a if a.size == size else np.concatenate([a, np.zeros(size - a.size, a.dtype)])


#: A record given as a function that starts a pass over it: each call yields its
#: (sample times s, acceleration g with NaN where invalid) chunks from the start again.
Passes = Callable[[], Iterable[tuple[np.ndarray, np.ndarray]]]


def fit_drift(t_s, acc_g, period_s: float | None = None, block_s: float = 1.0) -> DriftFit:
    """Fit ε(t) = C1(1 − e^(−t/T)) + C2 to a standstill (acc in g, NaN where invalid).

    C2 absorbs the part's zero-g offset: on a standstill only offset + drift is seen.
    Raises ValueError when the record is too short for the block size.
    """
    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc_g, dtype=float)
    if t.size != a.size:
        raise ValueError("t_s and acc_g differ in length")
    return fit_drift_passes(lambda: [(t, a)], ArrayStore(), period_s, block_s)


def fit_drift_passes(passes: Passes, scratch: SeriesStore, period_s: float | None = None,
                     block_s: float = 1.0) -> DriftFit:
    """fit_drift over a record read in three passes of chunks (memory follows the chunk and
    the blocks; the full-rate phase for the Allan deviation waits in `scratch`):
    1. the block means, the ends, the sample period → the curve fit;
    2. the full-rate residual's means;
    3. its RMS and lag-1 autocorrelation, and the phase θ into `scratch`."""
    sums = RecordSums(block_s)
    for t, a in passes():
        sums.add(np.asarray(t, dtype=float), np.asarray(a, dtype=float))
    if sums.usable < 100:
        raise ValueError(f"a drift fit needs a standstill of many samples; {sums.usable} are usable")
    period = sums.median_period_s() if period_s is None else period_s
    bt, bm = sums.block_means()
    if bt.size < 30:
        raise ValueError(
            f"the standstill gives only {bt.size} blocks of {block_s:g} s; the fit needs at least 30 "
            f"(record {sums.t_last_s - sums.t_first_s:.0f} s: use a longer standstill or a shorter --block-s)"
        )
    t0 = sums.t_first_s
    span = float(bt[-1] - t0)
    t_rel = bt - t0
    first, last = float(np.mean(bm[: max(3, bm.size // 20)])), float(np.mean(bm[-max(3, bm.size // 20):]))
    p0 = (last - first, first, span / 5.0)
    bounds = ([-np.inf, -np.inf, max(period, 1e-6)], [np.inf, np.inf, 100.0 * span])
    # imported here: the daemon imports this module (noise terms) but never fits, and
    # scipy.optimize would add to its start
    from scipy.optimize import curve_fit

    params, cov = curve_fit(_drift_curve, t_rel, bm, p0=p0, bounds=bounds, maxfev=20000)
    c1, c2, time_constant = (float(v) for v in params)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, np.inf))
    model = DriftModel(c1_g=c1, c2_g=c2, time_constant_s=time_constant)
    block_residual = bm - _drift_curve(t_rel, c1, c2, time_constant)
    whiteness = ljung_box(block_residual)
    residual = _ResidualPasses(passes, model, t0)
    allan = allan_deviation_of_phase(residual.phase(scratch, period), sums.n, period)
    # below ~10 periods the anti-alias filter and the quantiser shape the curve, not N
    terms = noise_terms(allan, min_tau_s=10.0 * period, record_s=float(sums.t_last_s - t0))
    return DriftFit(
        model=model,
        c1_std_g=float(std[0]),
        c2_std_g=float(std[1]),
        time_constant_std_s=float(std[2]),
        covariance=cov,
        block_s=block_s,
        block_t_s=bt,
        block_mean_g=bm,
        block_residual_g=block_residual,
        residual_rms_g=residual.rms,
        full_rate_lag1=residual.lag1,
        whiteness=whiteness,
        acf=autocorrelation(block_residual, whiteness.lags),
        allan=allan,
        noise=terms,
        start_t_s=t0,
    )


class _ResidualPasses:
    """The full-rate residual a − ε(t − t0), pass by pass. Invalid samples take the model
    value (a zero residual) so that time stays uniform for the Allan deviation; the RMS and
    the lag-1 autocorrelation are those of the valid samples."""

    def __init__(self, passes: Passes, model: DriftModel, t0_s: float):
        self._passes = passes
        self._model = model
        self._t0_s = t0_s
        self.rms = math.nan
        self.lag1 = math.nan

    def _chunks(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for t, a in self._passes():
            a = np.asarray(a, dtype=float)
            good = np.isfinite(a)
            yield np.where(good, a - drift_g(np.asarray(t, dtype=float) - self._t0_s, self._model), 0.0), good

    def phase(self, scratch: SeriesStore, period_s: float) -> SeriesStore:
        """θ = (0, cumsum(r − mean r)) · period into `scratch`; sets rms and lag1 on the way."""
        n = n_good = 0
        total = total_good = 0.0
        for r, good in self._chunks():
            n += r.size
            n_good += int(good.sum())
            total += float(r.sum())
            total_good += float(r[good].sum())
        mean, mean_good = total / n, total_good / n_good
        squares = centred_squares = cross = 0.0
        previous = None  # the last centred valid residual of the chunk before
        carry = 0.0
        scratch.append(np.zeros(1))
        for r, good in self._chunks():
            x = r[good] - mean_good
            squares += float(np.dot(r[good], r[good]))
            centred_squares += float(np.dot(x, x))
            if x.size:
                joined = x if previous is None else np.concatenate([[previous], x])
                cross += float(np.dot(joined[:-1], joined[1:]))
                previous = float(x[-1])
            sums = np.cumsum(np.concatenate([[carry], r - mean]))[1:]
            carry = float(sums[-1])
            scratch.append(sums * period_s)
        self.rms = math.sqrt(squares / n_good)
        self.lag1 = cross / centred_squares if centred_squares > 0.0 else 0.0
        return scratch
