"""Board counts to physical units: duty cycle → acceleration, T2 sums → sample time.

Each rule is written once as a scalar function in the subset of Python that numba
compiles (`duty_to_mps2`, `advance_sample_time`): the daemon's sample pipeline calls them
per sample from compiled code, and the vectorised forms for recordings
(`acceleration_mps2`, `sample_times_s`) are built on the very same functions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.jit import jit
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


@jit
def duty_to_mps2(duty, zero_g_duty, sensitivity_duty_per_g):
    """a = (T1/T2 − zero-g duty) / sensitivity · g (ADXL202 data sheet); scalars or arrays."""
    return (duty - zero_g_duty) / sensitivity_duty_per_g * STANDARD_GRAVITY_MPS2


def acceleration_mps2(t1_ticks, t2_ticks, cal: AxisCalibration):
    """Acceleration of one axis; NaN where the period is not a usable count."""
    t1 = np.asarray(t1_ticks, dtype=float)
    t2 = np.asarray(t2_ticks, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        duty = np.where(t2 > 0, t1 / t2, np.nan)
    duty = np.where((duty >= 0.0) & (duty <= 1.0), duty, np.nan)
    return duty_to_mps2(duty, cal.zero_g_duty, cal.sensitivity_duty_per_g)


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


@jit
def advance_sample_time(timed, next_t_s, last_period_s, t2_ticks, tick_hz, lost_before):
    """One sample's time and the timeline after it: (t_s, next_t_s, last_period_s).

    The board has no clock (spec): sample k's time is the sum of the periods before it,
    each sample's own period (T2) follows it. `timed`: a sample was timed before (else
    this one is t = 0, as after a board reset). Lost samples still took their time,
    each the period of the last sample received before the gap. An unusable count
    (T2 = 0) takes the last period (0 before any).
    """
    period = t2_ticks / tick_hz if t2_ticks > 0 else last_period_s
    t_s = next_t_s + lost_before * last_period_s if timed else 0.0
    return t_s, t_s + period, period


@jit
def _sample_times(t2, tick_hz, lost, clock, out):
    # clock: [timed (0/1), next sample's time, last period], carried from chunk to chunk
    timed = clock[0] > 0.0
    next_t = clock[1]
    last_period = clock[2]
    for k in range(t2.size):
        out[k], next_t, last_period = advance_sample_time(timed, next_t, last_period, t2[k], tick_hz, lost[k])
        timed = True
    clock[0] = 1.0 if timed else 0.0
    clock[1] = next_t
    clock[2] = last_period


class SampleClock:
    """`advance_sample_time` over a recording chunk by chunk: the chunks' times are those
    of the whole file (the timeline carries over), as the daemon times them."""

    def __init__(self, tick_hz: float):
        self.tick_hz = float(tick_hz)
        self._clock = np.zeros(3)

    def times(self, t2_ticks, lost_before=None) -> np.ndarray:
        t2 = np.ascontiguousarray(t2_ticks, dtype=np.float64)
        lost = (np.zeros(t2.size) if lost_before is None
                else np.ascontiguousarray(lost_before, dtype=np.float64))
        out = np.empty(t2.size)
        _sample_times(t2, self.tick_hz, lost, self._clock, out)
        return out


def sample_times_s(t2_ticks, tick_hz: float, lost_before=None) -> np.ndarray:
    """Time of every sample of a recording, as the daemon times them (`advance_sample_time`)."""
    t2 = np.asarray(t2_ticks, dtype=np.float64)
    if not (t2 > 0).any():
        raise ValueError("no sample has a usable period count (t2 > 0)")
    return SampleClock(tick_hz).times(t2, lost_before)
