"""What the diagnosis looks at: one recording's arrays, in SI units, plus what the baseline knows."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.diagnosis.reading import NoiseModel, WHITE, reading_from_steps, reference_steps
from gateway.core.units import STANDARD_GRAVITY_MPS2

G = STANDARD_GRAVITY_MPS2
# The baseline's drift shape ε(t) ∝ 1 − e^(−t/T): T from the sensor model (30 min); on a
# record of seconds it is a straight line, on hours the paper's exponential.
DRIFT_TIME_CONSTANT_S = 1800.0


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

    def __post_init__(self) -> None:
        self.t_s = np.asarray(self.t_s, dtype=float)
        n = self.t_s.size
        for name in ("acc_mps2", "ref_pos_m", "ref_vel_mps", "ref_acc_mps2", "other_mps2", "temp_c", "t_host_s"):
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

    def column_ok(self, name: str, min_std: float = 0.0) -> bool:
        """True when the column exists, is mostly finite and varies by more than min_std."""
        x = getattr(self, name)
        if x is None:
            return False
        good = np.isfinite(x)
        return good.mean() > 0.9 and float(np.std(x[good])) > min_std


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

    where: np.ndarray = None  # received samples' places on the full grid (lost ones between)
    t_full: np.ndarray = None
    reading_full: np.ndarray = None  # reading_mps2 on the full grid

    def full_reading(self, level0: float, step_t, step_size) -> np.ndarray:
        """The baseline sensor's reading of a piecewise-constant motion on the full grid."""
        return reading_from_steps(self.t_full, level0, step_t, step_size, self.data.sensor_bandwidth_hz)

    def set_reading(self, full: np.ndarray) -> None:
        self.reading_full = full
        self.reading_mps2 = full[self.where]

    def set_received_reading(self, received: np.ndarray) -> None:
        """A reading known at the received samples only (the smoothed estimate's)."""
        self.set_reading(np.interp(np.arange(self.t_full.size), self.where, received))


def rest_mask(t_s, ref_vel_mps, ref_acc_mps2, settle_s: float = 0.3) -> np.ndarray:
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
        prep.reference_steps = reference_steps(t, data.ref_vel_mps, data.ref_acc_mps2)
        prep.set_reading(prep.full_reading(*prep.reference_steps))
        prep.rest = rest_mask(t, data.ref_vel_mps, data.ref_acc_mps2)
    prep.rest &= data.valid
    return prep
