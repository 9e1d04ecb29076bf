"""Reference-point compensation (the paper's step 1): the DC offset measured at an initial rest.

The rest is found without a noise model: the first `min_rest_s` are taken as the
baseline (median, and σ from the median absolute deviation, robust to a stray spike);
the rest ends `guard_s` before the first valid sample more than `k_sigma`·σ away from
it. A motion of the paper's kind (10 m/s², σ ≈ 0.02 m/s²) is hundreds of σ.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
