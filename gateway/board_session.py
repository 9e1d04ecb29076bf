"""One board's frames → timed, converted samples: continuity, tick rate, temperature.

Pure bookkeeping (no I/O): the daemon feeds decoded frames, gets back samples with
their board time and acceleration along the configured axis, and events it must act
on (a board reset loses continuity).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.board_protocol import Hello, Sample, Status
from gateway.core.conversion import Calibration, SampleTimeline
from gateway.core.units import STANDARD_GRAVITY_MPS2

# A reading within 2 % of the ±2 g range is treated as clipped (the ADXL202 saturates
# a little beyond 2 g; the nominal duty cycle limits are 25 % and 75 %).
SATURATION_FRACTION = 0.98


@dataclass(slots=True)  # not frozen: built 500 times a second, and frozen init is slow
class TimedSample:
    t_s: float
    acc_mps2: float | None  # None: this axis carries no valid measurement
    saturated: bool
    lost_before: int
    seq: int


@dataclass
class SessionCounters:
    samples: int = 0
    samples_invalid: int = 0
    samples_saturated: int = 0
    # SAMPLEs that arrived before any STATUS/HELLO told the tick rate: time is unknown
    samples_without_tick_rate: int = 0
    # resets seen as HELLO, plus resets inferred from STATUS uptime going backwards
    resets_announced: int = 0
    resets_inferred: int = 0


def _acceleration_mps2(t1_ticks: int, t2_ticks: int, cal) -> float:
    """Scalar form of core.conversion.acceleration_mps2 (numpy on scalars costs ~10 µs a call)."""
    if t2_ticks <= 0 or not 0 <= t1_ticks <= t2_ticks:
        return math.nan
    return (t1_ticks / t2_ticks - cal.zero_g_duty) / cal.sensitivity_duty_per_g * STANDARD_GRAVITY_MPS2


class BoardSession:
    def __init__(self, calibration: Calibration, axis: str = "x", range_g: float = 2.0):
        if axis not in ("x", "y"):
            raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")
        self.calibration = calibration
        self.axis = axis
        self.range_g = range_g
        self.timeline = SampleTimeline()
        self.tick_hz: int | None = None
        self.temp_c: float | None = None
        self.uptime_s: int | None = None
        self.firmware: tuple[int, int] | None = None
        self.counters = SessionCounters()
        self.hellos_seen = 0

    def set_calibration(self, calibration: Calibration, axis: str) -> None:
        self.calibration = calibration
        self.axis = axis

    def on_report(self, frame: Status | Hello) -> bool:
        """Take a STATUS/HELLO; True when continuity was lost (a board reset)."""
        reset = False
        if isinstance(frame, Hello):
            self.hellos_seen += 1
            if self.hellos_seen > 1 or self.counters.samples:
                self.counters.resets_announced += 1
                reset = True
        elif self.uptime_s is not None and frame.uptime_s < self.uptime_s:
            # uptime went backwards without a HELLO: the board restarted and its HELLO was lost
            self.counters.resets_inferred += 1
            reset = True
        if reset:
            self.timeline.reset()
        self.tick_hz = frame.tick_hz if frame.tick_hz > 0 else self.tick_hz
        self.temp_c = frame.temp_c
        self.uptime_s = frame.uptime_s
        self.firmware = (frame.fw_major, frame.fw_minor)
        return reset

    def on_sample(self, frame: Sample) -> TimedSample | None:
        """None while the tick rate is unknown (no STATUS/HELLO yet): time cannot be told."""
        if self.tick_hz is None:
            self.counters.samples_without_tick_rate += 1
            return None
        self.counters.samples += 1
        t_s = self.timeline.advance(frame.t2_ticks, self.tick_hz, frame.lost_before)
        valid = frame.x_valid if self.axis == "x" else frame.y_valid
        t1 = frame.t1x_ticks if self.axis == "x" else frame.t1y_ticks
        acc = _acceleration_mps2(t1, frame.t2_ticks, getattr(self.calibration, self.axis)) if valid else math.nan
        saturated = bool(frame.flags & 0x07)
        if not math.isfinite(acc):
            self.counters.samples_invalid += 1
            return TimedSample(t_s, None, saturated, frame.lost_before, frame.seq)
        if abs(acc) >= SATURATION_FRACTION * self.range_g * STANDARD_GRAVITY_MPS2:
            saturated = True
        if saturated:
            self.counters.samples_saturated += 1
        return TimedSample(t_s, acc, saturated, frame.lost_before, frame.seq)
