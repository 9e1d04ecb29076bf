"""Board counts to physical units: duty cycle → acceleration, T2 sums → sample time.

Every function here has a vectorised form (for recordings) and the streaming wrapper
``SampleTimeline`` (for the daemon) is tested against it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.units import SEQ_MODULUS, STANDARD_GRAVITY_MPS2

FLAG_X_TIMEOUT = 0x01
FLAG_Y_TIMEOUT = 0x02
FLAG_TIMER_OVERFLOW = 0x04
# Bits 3–7 are 0 in protocol version 1; a sample with any of them set comes from a board
# speaking something else, and neither axis is trusted (the codec reads it the same way).
FLAGS_RESERVED = 0xF8


@dataclass(frozen=True)
class AxisCalibration:
    """a[g] = (T1/T2 − zero_g_duty) / sensitivity_duty_per_g (ADXL202 data sheet)."""

    zero_g_duty: float = 0.5
    sensitivity_duty_per_g: float = 0.125

    def __post_init__(self) -> None:
        if not 0.0 < self.zero_g_duty < 1.0:
            raise ValueError(f"zero_g_duty must be in (0, 1), got {self.zero_g_duty}")
        if not 0.0 < self.sensitivity_duty_per_g < 1.0:
            raise ValueError(
                f"sensitivity_duty_per_g must be in (0, 1), got {self.sensitivity_duty_per_g}"
            )


@dataclass(frozen=True)
class Calibration:
    x: AxisCalibration = AxisCalibration()
    y: AxisCalibration = AxisCalibration()


def acceleration_mps2(t1_ticks, t2_ticks, cal: AxisCalibration):
    """Acceleration of one axis; NaN where the period is not a usable count."""
    t1 = np.asarray(t1_ticks, dtype=float)
    t2 = np.asarray(t2_ticks, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        duty = np.where(t2 > 0, t1 / t2, np.nan)
    duty = np.where((duty >= 0.0) & (duty <= 1.0), duty, np.nan)
    return (duty - cal.zero_g_duty) / cal.sensitivity_duty_per_g * STANDARD_GRAVITY_MPS2


def axis_valid(flags, t1_ticks, t2_ticks, axis: str):
    """The spec's flag rules plus counts that cannot be a duty cycle (T2 = 0, T1 > T2)."""
    flags = np.asarray(flags, dtype=np.int64)
    timeout_bit = FLAG_X_TIMEOUT if axis == "x" else FLAG_Y_TIMEOUT
    t1 = np.asarray(t1_ticks)
    t2 = np.asarray(t2_ticks)
    return ((flags & (timeout_bit | FLAG_TIMER_OVERFLOW | FLAGS_RESERVED)) == 0) & (t2 > 0) & (t1 <= t2)


def lost_before_from_seq(seq) -> np.ndarray:
    """Samples lost on the line before each sample, from seq gaps (wrap-around 65535 → 0)."""
    seq = np.asarray(seq, dtype=np.int64)
    lost = np.zeros(seq.shape, dtype=np.int64)
    if seq.size > 1:
        lost[1:] = (np.diff(seq) - 1) % SEQ_MODULUS
    return lost


def period_s(t2_ticks, tick_hz: float) -> np.ndarray:
    """Each sample's own period; an unusable count (0) takes the last good period."""
    t2 = np.asarray(t2_ticks, dtype=float)
    good = t2 > 0
    if not good.any():
        raise ValueError("no sample has a usable period count (t2 > 0)")
    # forward-fill bad counts with the previous good one (the first good for a leading run)
    idx = np.where(good, np.arange(t2.size), 0)
    np.maximum.accumulate(idx, out=idx)
    filled = t2[idx]
    first_good = t2[np.argmax(good)]
    filled = np.where(good | (np.arange(t2.size) > np.argmax(good)), filled, first_good)
    return filled / float(tick_hz)


def sample_times_s(t2_ticks, tick_hz: float, lost_before=None) -> np.ndarray:
    """Time of sample k = the sum of the sensor periods before it (spec: the board has no clock).

    Sample k's own period follows it. Lost samples still took their time: each lost
    period is taken as the period of the last sample received before the gap.
    """
    periods = period_s(t2_ticks, tick_hz)
    lost = np.zeros(periods.shape, dtype=float) if lost_before is None else np.asarray(lost_before, float)
    step = np.zeros(periods.shape, dtype=float)
    step[1:] = periods[:-1] * (1.0 + lost[1:])
    return np.cumsum(step)


class SampleTimeline:
    """Streaming form of ``sample_times_s``: one sample in, its time out."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """A board reset (HELLO) restarts time at zero."""
        self._next_t_s: float | None = None
        self._last_period_s: float | None = None

    @property
    def state(self) -> tuple[float, float] | None:
        """(next sample's time s, last period s), None before the first sample: for a
        compiled caller that advances the timeline itself and hands it back (`resume`)."""
        if self._next_t_s is None:
            return None
        return self._next_t_s, self._last_period_s

    def resume(self, next_t_s: float, last_period_s: float) -> None:
        """Continue from a state that `advance` would have reached (see `state`)."""
        self._next_t_s = next_t_s
        self._last_period_s = last_period_s

    def advance(self, t2_ticks: int, tick_hz: float, lost_before: int = 0) -> float:
        period = t2_ticks / tick_hz if t2_ticks > 0 else self._last_period_s
        if self._next_t_s is None:
            t_s = 0.0
        else:
            t_s = self._next_t_s + lost_before * self._last_period_s
        if period is None:  # no usable period seen yet: time cannot advance
            period = 0.0
        self._last_period_s = period
        self._next_t_s = t_s + period
        return t_s
