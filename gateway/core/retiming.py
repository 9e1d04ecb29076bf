"""Sample times from arrival times: the regular sensor clock behind a logger's bursty timestamps.

A logger that stamps each sample when the PC receives it gives arrival times
a_i = τ_i + d_i: the sample time τ_i plus a delay d_i ≥ 0 that is near its floor for
some samples (the last one of a USB burst) and large for others (a backlog flushed at
start-up, a stall). Behind them the sensor's clock is regular: τ_i = t0 + T·k_i, k_i the
sample's index on that clock; k_i − k_{i−1} − 1 samples were lost before row i.

The line (Moon, Skelly & Towsley, "Estimation and removal of clock skew from network
delay measurements", INFOCOM 1999): the line t0 + T·k under every arrival and as high
as possible on average, max Σ τ_i subject to τ_i ≤ a_i. Only the least-delayed
arrivals decide it, so bursts do not bias it; T is the sensor's period measured on the
PC's clock, any clock-rate mismatch included. It is fitted to the rows outside late
stretches (a backlog is above it anyway, but would move the middle it is made highest
at); the first T is the median of the lines of 16 chunks, backlog chunks left out.

Gaps: a lost sample makes every later arrival one period later against the line, so the
floor of the delays steps up and stays up; a burst, a backlog or a stall does not move
it. The floor before a row (least delay over `confirm_s`) against the floor after it
(over 4·`confirm_s`): a step of at least half a period is a gap of round(step / T)
samples, put right after the last row on the old floor (the latest sample times the
arrivals allow). Then the line again with the new indices, until no new gap appears.
Last, the slope from the least delay of every `window_s` window (Theil–Sen), not only
the two points the line rests on, and the line lowered until it is under every arrival.

What arrival times cannot show, and `Retiming` says: a gap inside a backlog before the
first on-time arrival, or in the last `confirm_s`; where between two arrivals on the
floor a sample was lost; and whether a late stretch that lasts to the end is a logger
falling behind or the period found is a start-up flush's (`falling_behind`: only a
nominal rate can tell).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import minimum_filter1d
from scipy.stats import theilslopes

from gateway.core.runs import true_runs


@dataclass(frozen=True)
class RetimingSettings:
    min_rows: int = 20  # fewer arrivals cannot show a floor and a slope
    gap_min_periods: float = 0.5  # a floor step this large (in periods) is a gap
    confirm_s: float = 1.0  # a gap needs the floor seen this long after it
    late_s: float = 0.1  # a delay above this is "late": a backlog or a stall, reported
    window_s: float = 1.0  # windows in which the residual floor is reported
    max_passes: int = 20  # fit → gaps → fit …; converges in 2–3 on real files
    # the sensor's rate from its data sheet or configuration, if known: the period is then
    # sought only within rate_tolerance of it (needed when a backlog is most of the file)
    nominal_rate_hz: float | None = None
    rate_tolerance: float = 0.1


@dataclass(frozen=True)
class LateEpisode:
    start: int  # first row (0-based)
    stop: int  # exclusive
    max_delay_s: float
    arrival_interval_s: float  # median arrival spacing inside: a flush is faster than the sensor


@dataclass(frozen=True)
class Retiming:
    """Recovered sample times (on the arrival clock) and what the arrivals showed."""

    t_s: np.ndarray  # τ_i = t0 + T·k_i, same clock and origin as the arrival times given
    sample_index: np.ndarray  # k_i, 0 at the first row
    lost_before: np.ndarray  # samples lost before each row (gaps)
    period_s: float  # T on the arrival clock
    delay_s: np.ndarray  # a_i − τ_i ≥ 0
    on_time: np.ndarray  # rows outside late episodes
    floor_s: np.ndarray  # least delay in each window_s window outside late episodes: the fit residual
    late: tuple[LateEpisode, ...]
    bursts: int  # runs of ≥ 2 rows arriving less than half a period apart
    burst_rows_median: float
    burst_interval_s: float  # median arrival spacing inside bursts
    between_bursts_s: float  # median arrival spacing otherwise
    unconfirmed_from: int  # rows from here on: a gap could not be confirmed
    passes: int

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """(row, samples lost before it) for every gap found."""
        rows = np.flatnonzero(self.lost_before)
        return [(int(r), int(self.lost_before[r])) for r in rows]

    @property
    def falling_behind(self) -> LateEpisode | None:
        """A late stretch to the very end that arrives slower than the period found.

        Either the logger fell behind the sensor for good, or the rows before it were a
        start-up backlog flushed faster than the sensor and the period found is the flush's.
        Arrival times alone cannot tell the two apart; a nominal rate can.
        """
        last = self.late[-1] if self.late else None
        if last and last.stop == self.t_s.size and last.arrival_interval_s > 1.5 * self.period_s:
            return last
        return None

    @property
    def blind_rows(self) -> int:
        """Rows at the start that no on-time arrival precedes: gaps among them are unseen."""
        first = self.late[0] if self.late and self.late[0].start == 0 else None
        return first.stop if first else 0


class RetimingError(ValueError):
    """The arrival times cannot be re-timed (too few, going backwards, not finite, no rate)."""

    def __init__(self, what: str, row: int | None = None):
        super().__init__(what if row is None else f"row {row}: {what}")
        self.what = what
        self.row = row  # 0-based among the arrival times given, where one row is to blame


def fit_floor_line(k: np.ndarray, a: np.ndarray, period_range_s: tuple[float, float] | None = None
                   ) -> tuple[float, float]:
    """(t0, T) of the highest line t0 + T·k under every (k_i, a_i), highest on average.

    max over T of g(T) = min_i (a_i − T·(k_i − k̄)): g is concave and piecewise linear,
    its slope is −(k_j − k̄) at the row j that attains the minimum, so the optimum is found
    by bisection on the sign of that slope; it is the lower hull's edge over k̄. With
    period_range_s, the best T within that range (g is concave: its end nearest the optimum).
    """
    c = k - k.mean()
    def slope_sign(T: float) -> float:
        return -c[np.argmin(a - T * c)]
    if period_range_s is None:
        span = (a.max() - a.min()) / max(k.max() - k.min(), 1)
        lo, hi = 0.0, 2.0 * span + np.finfo(float).tiny
        for _ in range(64):  # widen until the slope turns negative
            if slope_sign(hi) < 0:
                break
            lo, hi = hi, 2.0 * hi
    else:
        lo, hi = period_range_s
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if slope_sign(mid) > 0:
            lo = mid
        else:
            hi = mid
    T = 0.5 * (lo + hi)
    t0 = float(np.min(a - T * k))
    return t0, float(T)


def _min_ahead(x: np.ndarray, w: int) -> np.ndarray:
    """m_i = min(x[i : i + w]), shorter at the end."""
    return minimum_filter1d(x, size=w, mode="constant", cval=np.inf, origin=-(w // 2))


def _new_gaps(r: np.ndarray, T: float, window: int, min_periods: float) -> np.ndarray:
    """Samples lost before each row, from steps of the delay floor.

    The floor just before a boundary (least delay of the `window` rows up to it) against the
    floor after it (least delay of the next 4·window rows: a stall shorter than that, its
    rows all late, is not taken for a step). Local windows keep a slightly wrong slope from
    hiding a step the way a floor taken over the whole file would.
    """
    n = r.size
    before = _min_ahead(r[::-1], window)[::-1]  # min r[i − window + 1 … i]
    after = np.r_[_min_ahead(r, 4 * window)[1:], np.inf]  # min r[i + 1 … i + 4·window]
    step = after - before  # for the boundary between row i and row i + 1
    lost = np.zeros(n, dtype=np.int64)
    candidate = (step >= min_periods * T) & (np.arange(n) < n - window)  # the floor after must be seen
    for first, stop in true_runs(candidate):
        # m from the largest step; the gap goes at the first boundary after which every row is
        # at least m − ½ periods above the floor before it: the latest sample times the arrivals
        # allow (where between two floor contacts the sample was really lost, they cannot tell)
        m = int(round(step[first:stop].max() / T))
        if m > 0:
            at = first + int(np.argmax(step[first:stop] >= (m - 0.5) * T))
            lost[at + 1] += m
    return lost


def _first_period(a: np.ndarray, min_rows: int, late_s: float, period_range_s, chunks: int = 16) -> float:
    """The median of the floor lines' slopes in chunks of the file: a gap bends a few chunks,
    not most (a line over the whole file is pulled by every gap in it). Chunks in a backlog
    (late against the line of that median) are then left out: a flush is not the sensor's
    timing. A backlog in most chunks sets the first median, and only a nominal rate
    (period_range_s) can tell the sensor's period then."""
    size = max(a.size // chunks, min_rows)
    starts = range(0, a.size - size + 1, size)
    slopes = np.array([fit_floor_line(np.arange(s, s + size, dtype=float), a[s:s + size])[1] for s in starts])
    if period_range_s is not None:
        slopes = slopes[(slopes >= period_range_s[0]) & (slopes <= period_range_s[1])]
        if not slopes.size:
            return 0.5 * (period_range_s[0] + period_range_s[1])
        return float(np.median(slopes))
    T = float(np.median(slopes))
    k = np.arange(a.size, dtype=float)
    late = _late(a - (np.min(a - T * k) + T * k), late_s)
    on_time = np.array([not late[s:s + size].any() for s in starts])
    return float(np.median(slopes[on_time])) if np.count_nonzero(on_time) >= 3 else T


def _late(delay: np.ndarray, late_s: float) -> np.ndarray:
    """Rows in late episodes: a run delayed more than late_s, until the delay is back to typical
    (the median), so a draining backlog's tail is not taken for the sensor's timing."""
    typical = np.median(delay)
    mask = delay > late_s
    for start, stop in true_runs(delay > late_s):
        back = np.flatnonzero(delay[stop:] <= typical)
        mask[start:stop + (int(back[0]) if back.size else delay.size - stop)] = True
    return mask


def _refine_slope(k, a, t0: float, T: float, on_time: np.ndarray, window: int) -> tuple[float, float]:
    """The slope through the least delay of every window, not through two points only.

    The floor line rests on the two lowest arrivals around the middle; where they sit a
    little low by chance its slope is off by their difference over their distance. The
    least delays of all windows (Theil–Sen: a few windows in a drain or a stall do not
    matter) give the slope; the line is then lowered until it is under every arrival.
    """
    r = a - (t0 + T * k)
    ks, floors = [], []
    for s in range(0, k.size - window + 1, window):
        idx = np.arange(s, s + window)[on_time[s:s + window]]
        if 2 * idx.size >= window:  # a window mostly in a backlog's drain has no floor
            j = idx[np.argmin(r[idx])]
            ks.append(k[j])
            floors.append(r[j])
    if len(ks) < 5:  # too few for a median of slopes: the floor line stands
        return t0, T
    slope = theilslopes(floors, ks).slope
    T = T + slope
    return float(np.min(a - T * k)), float(T)


def _sensor_period(T: float) -> float:
    if not (np.isfinite(T) and T > 0):
        raise RetimingError("the arrival times show no sample rate: the line under them is flat "
                            "(most rows arrive at the same instant)")
    return T


def retime(arrival_s, settings: RetimingSettings = RetimingSettings()) -> Retiming:
    """Sample times behind arrival times (seconds, non-decreasing, in row order)."""
    a_in = np.asarray(arrival_s, dtype=float)
    n = a_in.size
    if n < settings.min_rows:
        raise RetimingError(f"{n} arrival times; re-timing needs at least {settings.min_rows}")
    bad = np.flatnonzero(~np.isfinite(a_in))
    if bad.size:
        raise RetimingError("arrival time is not finite", int(bad[0]))
    back = np.flatnonzero(np.diff(a_in) < 0)
    if back.size:
        raise RetimingError("arrival time goes backwards", int(back[0]) + 1)
    if a_in[-1] == a_in[0]:
        raise RetimingError("all arrival times are equal")
    origin = a_in[0]
    a = a_in - origin  # keep precision when the logger counts seconds since 1970

    lost = np.zeros(n, dtype=np.int64)
    k = np.arange(n, dtype=float)
    passes = 0
    confirm = 2
    bounds = None
    if settings.nominal_rate_hz is not None:
        nominal = 1.0 / settings.nominal_rate_hz
        bounds = (nominal / (1 + settings.rate_tolerance), nominal / (1 - settings.rate_tolerance))
    T = _first_period(a, settings.min_rows, settings.late_s, bounds)
    if not T > 0:  # most chunks arrived at one instant: the whole file's floor line, then
        T = _sensor_period(fit_floor_line(k, a, bounds)[1])
    t0 = float(np.min(a - T * k))
    while passes < settings.max_passes:  # the count is reported (Retiming.passes)
        passes += 1
        confirm = min(max(int(np.ceil(settings.confirm_s / T)), 2), n)
        new = _new_gaps(a - (t0 + T * k), T, confirm, settings.gap_min_periods)
        lost += new
        k = np.arange(n) + np.cumsum(lost).astype(float)
        # the line from the on-time rows only: a backlog is above it anyway, but would move
        # the middle the line is made highest at (into the backlog, if it is most of the file)
        late_mask = _late(a - (t0 + T * k), settings.late_s)
        if np.count_nonzero(~late_mask) >= settings.min_rows:
            T = _sensor_period(fit_floor_line(k[~late_mask], a[~late_mask], bounds)[1])
        else:
            T = _sensor_period(fit_floor_line(k, a, bounds)[1])
        t0 = float(np.min(a - T * k))
        if not new.any():
            break
    window = min(max(int(round(settings.window_s / T)), 2), n)
    late_mask = _late(a - (t0 + T * k), settings.late_s)
    t0, T = _refine_slope(k, a, t0, T, ~late_mask, window)
    tau = t0 + T * k
    delay = a - tau
    late_mask = _late(delay, settings.late_s)
    d_a = np.diff(a)
    late = tuple(
        LateEpisode(s, e, float(delay[s:e].max()),
                    float(np.median(d_a[s:e - 1])) if e - s >= 2 else float("nan"))
        for s, e in true_runs(late_mask)
    )
    # bursts: runs of arrival intervals shorter than half a period, outside late episodes
    on_time = ~late_mask
    quick = (d_a < 0.5 * T) & on_time[1:] & on_time[:-1]
    runs = true_runs(quick)
    burst_rows = np.array([e - s + 1 for s, e in runs], dtype=float)
    inside = d_a[quick]
    outside = d_a[~quick & on_time[1:] & on_time[:-1]]

    floors = [delay[s:s + window][on_time[s:s + window]] for s in range(0, n, window)]
    floor = np.array([f.min() for f in floors if f.size], dtype=float)

    return Retiming(
        t_s=tau + origin,
        sample_index=k.astype(np.int64),
        lost_before=lost,
        period_s=T,
        delay_s=delay,
        on_time=on_time,
        floor_s=floor,
        late=late,
        bursts=len(runs),
        burst_rows_median=float(np.median(burst_rows)) if runs else 0.0,
        burst_interval_s=float(np.median(inside)) if inside.size else float("nan"),
        between_bursts_s=float(np.median(outside)) if outside.size else float("nan"),
        unconfirmed_from=max(n - confirm, 0),
        passes=passes,
    )


@dataclass(frozen=True)
class TimingError:
    """Recovered times against trusted ones, the constant offset (unknowable from arrivals) removed."""

    offset_s: float  # median of recovered − trusted
    max_s: float
    rms_s: float
    interval_rms_s: float  # error of the spacing between neighbours: what integration feels


def timing_error(t_recovered_s, t_true_s) -> TimingError:
    e = np.asarray(t_recovered_s, dtype=float) - np.asarray(t_true_s, dtype=float)
    offset = float(np.median(e))
    e = e - offset
    de = np.diff(e)
    return TimingError(offset, float(np.abs(e).max()), float(np.sqrt(np.mean(e ** 2))),
                       float(np.sqrt(np.mean(de ** 2))) if de.size else 0.0)


def on_sample_clock(t_logged_s, values, t_s) -> np.ndarray:
    """A signal logged at other times (e.g. a robot's position written when each sample
    arrived), linearly interpolated at the sample times t_s; empty (NaN) cells are skipped,
    and outside the logged span it is unknown (NaN), not extrapolated."""
    t_logged = np.asarray(t_logged_s, dtype=float)
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v) & np.isfinite(t_logged)
    if np.count_nonzero(ok) < 2:
        return np.full(np.shape(t_s), np.nan)
    return np.interp(t_s, t_logged[ok], v[ok], left=np.nan, right=np.nan)
