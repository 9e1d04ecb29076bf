"""Reference-point compensation (the paper's step 1): the DC offset measured at an initial rest.

The rest is found without a noise model: the first `min_rest_s` are taken as the
baseline (median, and σ from the median absolute deviation, robust to a stray spike);
the rest ends `guard_s` before the first valid sample more than `k_sigma`·σ away from
it. A motion of the paper's kind (10 m/s², σ ≈ 0.02 m/s²) is hundreds of σ.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# scipy.special, not scipy.stats (the daemon's start: see estimator_settings)

MOTION_RUN = 3  # samples in a row a step off the rest that end it (see find_initial_rest)
RESOLUTION_SAMPLES = 200_000  # enough to see a logger's step, bounded for a 12-hour file
MAD_TO_SIGMA = 1.4826  # σ of a normal distribution from its median absolute deviation


class NoRestError(ValueError):
    """The recording does not begin with a standstill long enough to measure the offset.
    `moves_after_s`: where the motion that ended the rest began (None: another reason)."""

    def __init__(self, message: str, moves_after_s: float | None = None):
        super().__init__(message)
        self.moves_after_s = moves_after_s


@dataclass(frozen=True)
class Rest:
    start: int
    stop: int  # exclusive
    offset_mps2: float  # mean acceleration over the rest: zero-g offset (+ gravity on a tilted axis)
    sample_std_mps2: float

    @property
    def samples(self) -> int:
        return self.stop - self.start


def resolution(values) -> float:
    """The smallest step between two distinct values: a quantised logger's resolution,
    ~0 for data written as floats."""
    steps = np.diff(np.unique(np.asarray(values, dtype=float)))
    return float(steps.min()) if steps.size else 0.0


def find_initial_rest(acc_mps2, valid, period_s: float, min_rest_s: float = 0.2,
                      k_sigma: float = 8.0, guard_s: float = 0.05) -> Rest:
    a = np.asarray(acc_mps2, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(a)
    n_min = max(8, int(round(min_rest_s / period_s)))
    first_valid = np.flatnonzero(ok)
    if first_valid.size < n_min:
        raise NoRestError(f"only {first_valid.size} valid samples; a rest needs at least {n_min}")
    start = int(first_valid[0])
    head = a[start:start + n_min][ok[start:start + n_min]]
    if head.size < n_min // 2:
        raise NoRestError("the first samples are mostly invalid: no rest to measure the offset on")
    centre = float(np.median(head))
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(head - centre)))
    if sigma == 0.0:  # a quantised, noise-free signal: fall back to the plain spread
        sigma = float(np.std(head)) or 1e-12
    deviation = np.abs(a - centre)
    away = ok & (deviation > k_sigma * sigma)
    away[:start] = False
    # A logger that quantises coarser than the noise (10 mg) shows a still rest as one
    # value with a one-step flicker now and then; taken for motion 0.2 s into a 2 s rest,
    # that flicker refused the recording. A sample within a step and a half of the rest
    # level ends it only as part of MOTION_RUN such samples in a row; anything further off
    # ends it at once, as before (for data written as floats the step is ~0: no change).
    step = resolution(a[:RESOLUTION_SAMPLES][ok[:RESOLUTION_SAMPLES]])
    run = away[: a.size - MOTION_RUN + 1].copy()
    for lag in range(1, MOTION_RUN):
        run &= away[lag : a.size - MOTION_RUN + 1 + lag]
    motion = away & (deviation > 1.5 * step)
    motion[: run.size] |= run
    moving = np.flatnonzero(motion)
    end = int(moving[0]) if moving.size else a.size
    stop = end - int(round(guard_s / period_s)) if moving.size else end
    if stop - start < n_min:
        raise NoRestError(
            f"the recording moves after {(end - start) * period_s:.3f} s; a rest of at least "
            f"{min_rest_s:g} s is needed at its start", moves_after_s=(end - start) * period_s)
    rest = a[start:stop][ok[start:stop]]
    return Rest(start=start, stop=stop, offset_mps2=float(np.mean(rest)), sample_std_mps2=float(np.std(rest)))


# One false "motion" per this many windows of a true rest (each of the two tests), as the
# standstill detector's (EstimatorSettings.standstill_false_motion_prob)
QUIET_FALSE_MOTION_PROB = 1e-4
QUIET_WINDOW_S = 0.1  # the standstill detector's window (EstimatorSettings.standstill_window_s)


def quiet_part(acc_mps2, valid, rest: Rest, period_s: float, baseline_s: float = 0.2,
               window_s: float = QUIET_WINDOW_S, false_motion_prob: float = QUIET_FALSE_MOTION_PROB) -> Rest:
    """The part of an initial rest where every window of the recording is quiet on the scale
    of the recording's own noise — what the noise settings may be measured on.

    find_initial_rest ends a rest at the first sample far (8σ) off its start: a sensor whose
    other axes move while this one stands (cross-axis coupling, a mount that vibrates) stays
    "at rest" for seconds while its noise grows threefold, and the noise measured there is
    the motion's. Here each window of W samples (window_s) after the baseline (the rest's
    first baseline_s, n samples) is compared with the baseline by the two tests of a
    standstill detector, each at false-alarm probability p per window:
    - variance: s_w² / s_0² beyond the F(W − 1, n − 1) quantile at 1 − p (the ratio of two
      sample variances: the baseline's own uncertainty is in the test);
    - mean: |m_w − m_0| / (s_0·√(1/W + 1/n)) beyond Student's t(n − 1) at 1 − p/2.
    The quiet part ends at the first window that fails either. Never shorter than the
    baseline (the rest was found on it)."""
    a = np.asarray(acc_mps2, dtype=float)[rest.start:rest.stop]
    a = a[np.asarray(valid, dtype=bool)[rest.start:rest.stop] & np.isfinite(a)]
    n0 = max(8, int(round(baseline_s / period_s)))
    w = max(4, int(round(window_s / period_s)))
    if a.size < n0 + w:
        return rest
    head = a[:n0]
    m0, s0 = float(np.mean(head)), float(np.std(head, ddof=1))
    if s0 == 0.0:
        return rest  # a noise-free (quantised) baseline: no scale to test against
    windows = np.lib.stride_tricks.sliding_window_view(a[n0:], w)
    # scipy here, not at the top: the daemon imports this module and starts without scipy
    # (the slim install, gateway/core/chi2.py); only `adxlgw estimate` calls quiet_part
    from scipy.special import fdtri, stdtrit

    var_max = s0 * s0 * float(fdtri(w - 1, n0 - 1, 1.0 - false_motion_prob))
    mean_max = float(stdtrit(n0 - 1, 1.0 - 0.5 * false_motion_prob)) * s0 * np.sqrt(1.0 / w + 1.0 / n0)
    loud = (windows.var(axis=1, ddof=1) > var_max) | (np.abs(windows.mean(axis=1) - m0) > mean_max)
    if not loud.any():
        return rest
    kept = a[:n0 + int(np.argmax(loud))]
    # (indices of valid samples only: the stop is where the kept samples end in the recording)
    ok = np.flatnonzero(np.asarray(valid, dtype=bool)[rest.start:rest.stop] & np.isfinite(
        np.asarray(acc_mps2, dtype=float)[rest.start:rest.stop]))
    stop = rest.start + int(ok[kept.size - 1]) + 1
    return Rest(start=rest.start, stop=stop, offset_mps2=float(np.mean(kept)), sample_std_mps2=float(np.std(kept)))
