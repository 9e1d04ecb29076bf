"""What the diagnosis looks at: one recording's arrays, in SI units, plus what the baseline knows."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from gateway.core.diagnosis.reading import WHITE, NoiseModel, reading_from_steps, reference_steps
from gateway.core.filters import one_pole_lowpass
from gateway.core.runs import true_runs
from gateway.core.units import STANDARD_GRAVITY_MPS2

G = STANDARD_GRAVITY_MPS2
# The baseline's drift shape ε(t) ∝ 1 − e^(−t/T): T from the sensor model (30 min); on a
# record of seconds it is a straight line, on hours the paper's exponential.
DRIFT_TIME_CONSTANT_S = 1800.0
# the noise model is fitted on the rests each less its own mean (Prepared.noise_series): a
# rest of n points loses 1/n of its variance to its mean, and 16 keeps that under 7 %;
# fewer than 64 points in all and the rests are taken joined (fit_noise_model's own floor)
MIN_NOISE_REST = 16
MIN_NOISE_POINTS = 64
# a column an effect reads (the other axis, temp_c, t_host_s) is used when it covers this
# fraction of the rows: the model with the effect and the model without are compared on
# the same samples, and the rows it lacks are filled (held, interpolated) — a tenth of
# filled values stays a small part of what decides
USABLE_COLUMN_FRACTION = 0.9
# the board reports its temperature in 0.01 °C (board protocol): a column varying by less
# than 5 of its counts carries its own rounding (σ 0.003 °C), not a temperature change
MIN_TEMPERATURE_STD_C = 0.05


def held_samples_smoothed(t_s: np.ndarray, held: np.ndarray) -> np.ndarray:
    """A smooth quantity from a column that holds each report until the next one.

    The board's temperature reaches a recording once per second (STATUS) and each row
    carries the latest value: a staircase. An effect that follows the temperature
    follows the board's real one, which moves smoothly between reports (a thermal mass),
    and is on average half a report period ahead of the held value; regressed on the
    staircase, the steps leave a residual that reads as a wandering bias. So: each new
    value is taken as the temperature at its first row (when its report came), a
    value held longer than the usual report period (a temperature that did not move)
    as that value again every period, and a cubic spline goes through those points (the
    first value is left out: it was reported before the recording began, at a time not
    known; the spline's end pieces reach back to the first row).
    A column that changes at every row (a logger with a temperature per sample) has a
    point at every row: the spline goes through them all and returns it unchanged.
    NaN rows stay NaN; with fewer than four points the column is returned as it is.
    """
    held = np.asarray(held, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    good = np.flatnonzero(np.isfinite(held))
    if good.size < 4:
        return held.copy()
    tg, vg = t_s[good], held[good]
    first = np.concatenate([[0], np.flatnonzero(np.diff(vg) != 0) + 1])
    if first.size < 4 or first.size == vg.size:
        return held.copy()  # too few reports to shape, or a new value at every row: as it is
    # the usual report period: the median time a value is held
    period = float(np.median(np.diff(tg[first])))
    ends = np.append(tg[first[1:]], tg[-1])
    if first.size > 4:  # the first value was reported before the first row: when is not known
        first, ends = first[1:], ends[1:]
    t0 = tg[first]
    # a value held for several report periods: reported again at each (vectorised: a
    # 12-hour file has ~43 000 reports)
    repeats = np.maximum(np.floor((ends - t0) / period + 1e-9).astype(np.int64), 1) if period > 0 \
        else np.ones(first.size, np.int64)
    offsets = np.arange(int(repeats.sum())) - np.repeat(np.cumsum(repeats) - repeats, repeats)
    knot_t = np.repeat(t0, repeats) + offsets * period
    knot_v = np.repeat(vg[first], repeats)
    keep = np.concatenate([[True], np.diff(knot_t) > 0])
    knot_t, knot_v = knot_t[keep], knot_v[keep]
    if knot_t.size < 4:
        return held.copy()
    from scipy.interpolate import CubicSpline  # (imported here: only a temperature column needs it)

    spline = CubicSpline(knot_t, knot_v)
    # within a report period of the first and last points the spline's end pieces go on
    # (the temperature keeps moving after its last report); further out it is held
    out = np.full(held.shape, np.nan)
    out[good] = spline(np.clip(tg, knot_t[0] - period, knot_t[-1] + period))
    return out


@dataclass
class DiagnosisInput:
    """A recording as the diagnosis reads it. Arrays are one entry per received sample.

    reference: "recorded" when the file carries the reference motion, "estimated" when
    the smoothed estimate stands in for it (then only effects that a self-consistent
    estimate cannot absorb can be seen), None when there is neither.
    """

    t_s: np.ndarray
    acc_mps2: np.ndarray  # the measured axis; NaN where invalid
    valid: np.ndarray
    lost_before: np.ndarray
    reference: str | None = None
    ref_pos_m: np.ndarray | None = None
    ref_vel_mps: np.ndarray | None = None
    ref_acc_mps2: np.ndarray | None = None
    other_mps2: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    t_host_s: np.ndarray | None = None
    # the baseline sensor: its CX low-pass (None for a foreign sensor of unknown filter)
    # and its range, where it saturates (math.inf for a foreign sensor of unknown range)
    sensor_bandwidth_hz: float | None = None
    range_mps2: float = 2.0 * G
    raw_form: bool = True
    # the user says the other axis does not move (--other-axis-still): only then can its
    # reading of our motion be told from its own motion, which has no reference
    other_axis_still: bool = False
    # samples per interval of the reference's own resolution (1: it resolves every sample);
    # see reference_resolution_block
    reference_block: int = 1
    # the machine's word per sample (1 at rest, 0 moving, NaN unknown), when the recording
    # carries one: the distance estimates are the estimator as `adxlgw estimate` runs it on
    # this recording, hint included (gain.EstimatePlan)
    standstill_hint: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t_s = np.asarray(self.t_s, dtype=float)
        n = self.t_s.size
        for name in ("acc_mps2", "ref_pos_m", "ref_vel_mps", "ref_acc_mps2", "other_mps2", "temp_c", "t_host_s",
                     "standstill_hint"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=float)
                if value.size != n:
                    raise ValueError(f"{name} has {value.size} values for {n} samples")
                setattr(self, name, value)
        self.valid = np.asarray(self.valid, dtype=bool) & np.isfinite(self.acc_mps2)
        self.lost_before = np.asarray(self.lost_before, dtype=np.int64)

    def __len__(self) -> int:
        return self.t_s.size

    @property
    def period_s(self) -> float:
        return float(np.median(np.diff(self.t_s)))

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    @property
    def has_reference(self) -> bool:
        return self.ref_acc_mps2 is not None and self.ref_vel_mps is not None

    @functools.cached_property
    def temperature_c(self) -> np.ndarray | None:
        """The board temperature at each sample, from the temp_c column as recordings
        carry it: the latest STATUS value (docs: recording format; the board reports once
        per second in 0.01 °C), a staircase of a smooth quantity (`held_samples_smoothed`)."""
        return None if self.temp_c is None else held_samples_smoothed(self.t_s, self.temp_c)

    def column_ok(self, name: str, min_std: float = 0.0) -> bool:
        """True when the column exists, is mostly finite and varies by more than min_std."""
        x = getattr(self, name)
        if x is None:
            return False
        good = np.isfinite(x)
        return good.mean() > USABLE_COLUMN_FRACTION and float(np.std(x[good])) > min_std


@dataclass
class Prepared:
    """Derived once per diagnosis: the baseline's reading of the reference, rests, noise."""

    data: DiagnosisInput
    reading_mps2: np.ndarray  # what the baseline sensor reads of the reference motion
    rest: np.ndarray  # samples where the reference is at rest, away from motion edges
    drift_shape: np.ndarray
    fit_mask: np.ndarray  # samples every model is compared on
    noise: NoiseModel = WHITE
    reference_steps: tuple = (0.0, np.zeros(0), np.zeros(0))

    @property
    def n_fit(self) -> int:
        return int(self.fit_mask.sum())

    # samples per comparison block: 1 compares every sample; a coarse reference (a robot
    # position at a few Hz) has no acceleration detail within its own interval, so model
    # and measurement are compared as block means there (= velocity changes per block)
    block: int = 1
    where: np.ndarray = None  # received samples' places on the full grid (lost ones between)
    t_full: np.ndarray = None
    reading_full: np.ndarray = None  # reading_mps2 on the full grid

    @property
    def compare_period_s(self) -> float:
        return self.data.period_s * self.block

    def _block_means(self, x: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean, first sample, samples) of each comparison block whose samples all lie in
        mask, in order. Blocks of `block` samples are laid from the record's first sample;
        when the record is not a whole number of blocks its last block is partial (its
        samples are often the final rest, where the distance is scored): compared too, as
        the mean of its own samples (its weight: whiten_masked)."""
        b = self.block
        starts = np.arange(0, x.size, b)
        if starts.size == 0:
            return np.zeros(0), starts, starts
        counts = np.minimum(b, x.size - starts)
        sums = np.add.reduceat(np.where(mask, x, 0.0), starts)
        inside = np.add.reduceat(np.asarray(mask, dtype=np.int64), starts) == counts
        return (sums / counts)[inside], starts[inside], counts[inside]

    def blocks(self, x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Means of x over the comparison blocks whose samples all lie in mask (in order),
        the record's last partial block included (`_block_means`)."""
        return self._block_means(x, mask)[0]

    def compared_index(self, mask: np.ndarray) -> np.ndarray:
        """The sample index of each value whiten_masked returns (a block's first sample)."""
        if self.block == 1:
            return np.flatnonzero(mask)
        return self._block_means(np.zeros(mask.size), mask)[1]

    def whiten_masked(self, x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """x over mask, as the models are compared: whitened by the noise model, per sample
        or per comparison block.

        A partial block's mean averages m < b samples: its noise variance is b/m times a
        full block's where the sensor's noise is white within a block, and less where the
        sensor's low-pass correlates it from sample to sample (a mean of fewer samples
        then loses less to averaging). So its whitened value is weighted by √(m/b): a
        full block's variance for white noise, never more for positively correlated
        noise — the likelihood's one variance holds, and a short block never counts above
        what it knows (tests/diagnosis/test_diagnosis_partial_block.py). The weight
        multiplies the block's innovation under the noise model; with an ARMA model the
        part carried from the block before is weighted with it (the model is fitted on
        full blocks' means).
        """
        if self.block == 1:
            return self.noise.whiten(np.where(mask, x, 0.0))[mask]
        means, _, counts = self._block_means(np.nan_to_num(x), mask)
        return self.noise.whiten(means) * np.sqrt(counts / self.block)

    def noise_series(self, residual: np.ndarray) -> np.ndarray:
        """The residual over the rests, at the comparison's rate, each rest less its own
        mean: what the noise model is fitted on.

        The noise model says how the sensor's noise is correlated from one sample to the
        next; what moves a rest's level as a whole (a temperature that swings, a tilt at
        another place, a drift the baseline's line misses) is what the candidates are
        there to explain. Joined with their levels, the rests' steps read as noise
        correlated over seconds (an AR pole at its bound, 0.98), and whitened by that
        model a slow effect loses its evidence: a ±6 mg temperature swing gained
        nothing (ΔBIC > 0). Rests of fewer than MIN_NOISE_REST points (whose own mean
        would take a visible share of their noise) are left out, unless fewer than
        MIN_NOISE_POINTS would remain: then the rests are taken joined, as before."""
        if self.block == 1:
            ok = self.rest & np.isfinite(residual)
            x = np.nan_to_num(residual)
        else:
            b = self.block
            n = residual.size // b * b
            ok = (self.rest & np.isfinite(residual))[:n].reshape(-1, b).all(axis=1)
            x = np.nan_to_num(residual)[:n].reshape(-1, b).mean(axis=1)
        pieces = [x[a:e] - x[a:e].mean() for a, e in true_runs(ok) if e - a >= MIN_NOISE_REST]
        if sum(p.size for p in pieces) < MIN_NOISE_POINTS:
            return x[ok]
        return np.concatenate(pieces)

    def level_at_rest(self, acc: np.ndarray) -> np.ndarray:
        """What acc reads when nothing moves, over the whole record: the baseline's offset
        and drift (its line through drift_shape) fitted on the received samples at rest."""
        ok = self.rest & self.data.valid & np.isfinite(acc)
        if ok.sum() < 2:
            return np.zeros_like(acc)
        x = np.column_stack([np.ones(acc.size), self.drift_shape])
        coef = np.linalg.lstsq(x[ok], acc[ok], rcond=None)[0]
        return x @ coef

    def full_reading(self, level0: float, step_t, step_size) -> np.ndarray:
        """The baseline sensor's reading of a piecewise-constant motion on the full grid."""
        return reading_from_steps(self.t_full, level0, step_t, step_size, self.data.sensor_bandwidth_hz)

    def delayed_reading(self, delay_s: float) -> np.ndarray:
        """The baseline's reading of the reference read delay_s later (the motion at t is
        the reference at t + d), on the full grid.

        A fine reference is piecewise-constant acceleration: its steps move, and the
        filtered period means are made anew exactly. A coarse one (block > 1) is not:
        each period's mean acceleration is its velocity change over the period, exact
        for any motion, then the sensor's filter (one pole, discretised per period)."""
        if self.block == 1:
            level0, step_t, step_size = self.reference_steps
            return self.full_reading(level0, step_t - delay_s, step_size)
        d = self.data
        t = self.t_full
        edges = np.append(t, t[-1] + d.period_s) + delay_s
        v = np.interp(edges, d.t_s, d.ref_vel_mps)
        mean = np.diff(v) / np.diff(edges)
        bw = d.sensor_bandwidth_hz
        return mean if bw is None or not np.isfinite(bw) else one_pole_lowpass(mean, d.period_s, bw)

    def set_reading(self, full: np.ndarray) -> None:
        self.reading_full = full
        self.reading_mps2 = full[self.where]

    def set_received_reading(self, received: np.ndarray) -> None:
        """A reading known at the received samples only (the smoothed estimate's)."""
        self.set_reading(np.interp(np.arange(self.t_full.size), self.where, received))


# a rest starts this long after the last motion: 100 time constants of the part's 50 Hz
# pole, and a mount's ringing with ζ·f0 ≥ 3 Hz (ζ 0.1 at 30 Hz) down by e^(−2π·ζ·f0·t) < e⁻⁵;
# a lighter ringing is left in the rests, where it reads as noise colour, not as an effect
REST_SETTLE_S = 0.3


def rest_mask(t_s, ref_vel_mps, ref_acc_mps2, settle_s: float = REST_SETTLE_S) -> np.ndarray:
    """At rest by the reference and settle_s past the last motion (ringing, filter tails)."""
    t = np.asarray(t_s, dtype=float)
    still = (np.abs(ref_vel_mps) < 1e-6) & (np.abs(ref_acc_mps2) < 1e-9)
    moving_t = t[~still]
    if moving_t.size == 0:
        return still
    # time since the last moving sample
    idx = np.searchsorted(moving_t, t, side="right") - 1
    since = np.where(idx >= 0, t - moving_t[np.maximum(idx, 0)], np.inf)
    return still & (since >= settle_s)


def prepare(data: DiagnosisInput) -> Prepared:
    t = data.t_s
    drift_shape = -np.expm1(-(t - t[0]) / DRIFT_TIME_CONSTANT_S)
    prep = Prepared(data, np.zeros(t.size), np.ones(t.size, dtype=bool), drift_shape, data.valid.copy())
    # the full sample grid: lost samples (seq gaps) take their place, times interpolated
    prep.where = np.arange(t.size) + np.cumsum(data.lost_before)
    n_full = int(prep.where[-1]) + 1 if t.size else 0
    prep.t_full = np.interp(np.arange(n_full), prep.where, t) if t.size else t
    prep.set_reading(np.zeros(n_full))
    if data.has_reference:
        prep.block = max(1, int(data.reference_block))
        prep.reference_steps = reference_steps(t, data.ref_vel_mps, data.ref_acc_mps2)
        prep.set_reading(prep.delayed_reading(0.0))
        prep.rest = rest_mask(t, data.ref_vel_mps, data.ref_acc_mps2)
    prep.rest &= data.valid
    return prep


def reference_resolution_block(t_s, ref_pos_m, moving: np.ndarray | None = None) -> int:
    """How many samples one step of a coarse position reference spans.

    A position logged at a few Hz and interpolated (linearly) to the samples bends only
    at its own samples: the median time between bends while moving, in sample periods.
    A reference that resolves every sample (a simulation's truth, a fast encoder) bends
    at every sample of an acceleration phase and gives 1.
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(ref_pos_m, dtype=float)
    if t.size < 10:
        return 1
    period = float(np.median(np.diff(t)))
    slope = np.diff(x) / np.diff(t)
    # a bend: a slope change above 10 % of the largest (sample times rounded to timer
    # ticks make small ones, ~5 %, all along a cruise)
    change = np.abs(np.diff(slope))
    bend = change > 0.1 * max(float(np.max(change)), 1e-12)
    idx = np.flatnonzero(bend) + 1
    if moving is not None:
        idx = idx[np.asarray(moving, dtype=bool)[idx]]
    if idx.size < 5:
        return 1
    # runs of consecutive bends: a knot inside a sample interval bends the line on both
    # sides of it (runs of 1–2); a fine reference bends on every sample of an
    # acceleration phase (long runs)
    starts = np.concatenate([[True], np.diff(idx) > 1])
    run_len = np.diff(np.append(np.flatnonzero(starts), idx.size))
    if np.median(run_len) > 2:
        return 1
    idx = idx[starts]
    if idx.size < 5:
        return 1
    gaps = np.diff(t[idx]) / period
    return max(1, int(round(float(np.median(gaps)))))
