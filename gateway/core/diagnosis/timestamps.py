"""The two clocks of a recording, checked before anything is analysed.

- The sample clock (t_s): the board's T2 periods, or a foreign sensor's own clock. Its
  intervals are its period within a timer tick (a few µs at 500 samples/s; the robot
  files' sensors: 0.99–1.01 of their period), or whole multiples of it across lost
  samples. An interval below HALF the clock's period is not a sample clock's: no
  oscillator is 50 % off (an RC clock is within ±2 %), so such rows were stamped when
  they arrived (a logger's bursts). The mean period is taken over the span, lost
  samples counted, so bursts cannot hide it. A file stamped that way is refused (exit 2)
  with the command that recovers its sample times (`adxlgw import --arrival-col`,
  gateway/core/retiming.py), rather than analysed on a clock it does not have.
- The host's arrival times (t_host_s): what a logger or a gateway stamping on arrival
  has. They may come in bursts, repeat (zero intervals) and even step backwards (a
  host clock set back, rows written out of order). All of that is a finding (the
  `timing` effect), not a reason to stop; but an estimate on host times needs them
  strictly increasing, so when they are not, the host-timed estimate is "not
  available" with the count that says why (never a division by a zero period).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.retiming import RetimingError, retime

# below half its period an interval is not a sample clock's (module docstring)
MIN_INTERVAL_PERIODS = 0.5


class TimestampError(ValueError):
    """The sample times cannot be a sample clock; the message names what and where."""


@dataclass(frozen=True)
class HostClock:
    """What the host's arrival times are like (JSON: `timestamps.host`)."""

    rows: int
    non_finite: int
    backwards: int  # intervals < 0
    zero_intervals: int  # intervals == 0
    burst_intervals: int  # 0 < interval < half the sample period
    period_s: float  # the sensor's period on the host clock (retiming), NaN when it cannot be found
    why_not_retimed: str = ""

    @property
    def strictly_increasing(self) -> bool:
        return self.non_finite == 0 and self.backwards == 0 and self.zero_intervals == 0

    def to_dict(self) -> dict:
        return {"rows": self.rows, "non_finite": self.non_finite, "backwards": self.backwards,
                "zero_intervals": self.zero_intervals, "burst_intervals": self.burst_intervals,
                "strictly_increasing": self.strictly_increasing,
                "period_s": self.period_s if np.isfinite(self.period_s) else None,
                "why_not_retimed": self.why_not_retimed}

    def why_no_estimate(self) -> str | None:
        """Why no estimate can run on these times (None: it can)."""
        if self.strictly_increasing:
            return None
        parts = [f"{n} {what}" for n, what in ((self.backwards, "backward steps"),
                                                (self.zero_intervals, "zero intervals"),
                                                (self.non_finite, "non-finite values")) if n]
        return (f"host arrival times are not increasing ({', '.join(parts)} in {self.rows} rows): "
                "no estimate can run on them")


def check_sample_clock(t_s, lost_before) -> float:
    """The sample clock's mean period (s), lost samples counted; TimestampError when t_s
    is not a sample clock (not finite, not increasing, or bursty: module docstring)."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 2:
        raise TimestampError(f"t_s: {t.size} sample time(s); at least 2 are needed")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise TimestampError(f"t_s: row {int(bad[0]) + 1}: sample time is not finite")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        raise TimestampError(f"t_s: row {int(back[0]) + 2}: sample time does not increase "
                             f"({back.size} such rows)")
    lost = np.asarray(lost_before, dtype=np.int64)
    slots = t.size - 1 + int(lost[1:].sum()) if lost.size == t.size else t.size - 1
    period = float(t[-1] - t[0]) / max(slots, 1)
    short = np.flatnonzero(dt < MIN_INTERVAL_PERIODS * period)
    if short.size:
        raise TimestampError(
            f"t_s: {short.size} of {dt.size} intervals are under half the clock's mean period "
            f"({period * 1e3:.3g} ms; first at row {int(short[0]) + 2}, {dt[short[0]] * 1e3:.3g} ms): these are "
            "arrival times in bursts, not a sample clock — recover the sample times first "
            "(adxlgw import … --arrival-col COLUMN)")
    return period


def check_host_clock(t_host_s, sample_period_s: float) -> HostClock:
    """Count what is irregular in the host's arrival times; the sensor's period on the
    host clock from the re-timing's floor line where the times allow it."""
    h = np.asarray(t_host_s, dtype=float)
    finite = np.isfinite(h)
    d = np.diff(h[finite])
    backwards = int(np.count_nonzero(d < 0))
    zero = int(np.count_nonzero(d == 0))
    burst = int(np.count_nonzero((d > 0) & (d < MIN_INTERVAL_PERIODS * sample_period_s)))
    period, why = float("nan"), ""
    try:
        period = retime(h[finite]).period_s
    except RetimingError as err:
        why = str(err)
    return HostClock(int(h.size), int(np.count_nonzero(~finite)), backwards, zero, burst, period, why)
