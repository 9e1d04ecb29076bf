"""The machine's standstill hint's latency, measured on the recording itself.

A controller says "in position" when its own loop is done, not when the sensor on the
tool stops: the word may lead the sensor's stop (a PLC cycle, a fieldbus, a servo still
settling) or trail it, and "moving" may lead or trail the sensor's start alike. The hint
gate (standstill.hint_gate_open) trusts a hinted window only where the accelerometer
agrees, but a hint shifted by a window's length puts a whole deceleration or start into
its "at rest" — and the latency differs from plant to plant, so no one number fits
(docs/estimation.md, "The machine's standstill hint").

The accelerometer itself shows where the machine's motion ends and begins: the pulses of
its starts and stops. The latency is the shift of the hint that puts each of its edges at
the boundary between the quiet and the moving samples around it:

- around each edge of the hint (rest → moving or moving → rest), on the samples nearer to
  it than to its neighbouring edges and within MAX_LATENCY_S, each sample scores
  e = (z − m)² − τ, m the median acceleration there (the bias, whatever tilt or offset),
  τ = σ²·χ²₁(1 − p): a sample of rest noise (σ from the samples' own MAD) exceeds τ with
  probability p, the detector's false-alarm rate. A sample that is no rest noise scores
  > 0, a quiet one < 0;
- the edge's latency is the shift L that minimises the sum of e over the samples the
  shifted hint calls "at rest" — as much quiet time as possible inside the rest, no
  pulse;
- the recording's latency is the median over its edges (robust to an edge whose
  neighbourhood holds other motion: the other axes moving, a tool turning), reported
  with the edges' spread.

`estimate_series` measures it and says so in its notes; it aligns the hint by it only
when asked (align_hint): aligned to the accelerometer's own edges the hint made the
corpus worse, because the hint gate needs a whole quiet window inside the hinted rest and
the edges the accelerometer shows lie a sensor-filter tail or a ring later than the
machine's (docs/decisions/0120-hint-latency-measured-not-applied.md). The daemon takes
the hint as it comes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gateway.core.chi2 import chi2_isf
from gateway.core.reference_point import MAD_TO_SIGMA

# The largest latency searched (either way), a physical bound: a PLC cycle (1–20 ms), a
# fieldbus (1–10 ms) and a servo's settling into its in-position window (tens of ms, up to
# ~100 ms) add to at most ~0.1 s; searched to three times that, so a true latency is never
# at the edge of the search.
MAX_LATENCY_S = 0.3
# The fewest edges whose median is a latency: with three, one edge whose neighbourhood
# holds other motion (the other axes moving, a tool turning) cannot move the median.
MIN_EDGES = 3


@dataclass(frozen=True)
class HintLatency:
    """How much later than the machine's hint the accelerometer's own edges come (> 0:
    the hint leads the sensor), from `edges` edges of the hint; None when no edge could
    be judged. edge_lags_s: each edge's own estimate."""

    lag_s: float | None
    edges: int
    edge_lags_s: tuple[float, ...]

    def describe(self, applied: bool) -> str:
        if self.lag_s is None:
            return (f"the hint's latency not measured ({self.edges} edges of the hint with samples around them, "
                    f"{MIN_EDGES} needed): the hint is used as it came")
        lo, hi = min(self.edge_lags_s), max(self.edge_lags_s)
        lead = "leads" if self.lag_s >= 0 else "trails"
        return (f"the machine's hint {lead} the accelerometer's own starts and stops by "
                f"{abs(self.lag_s) * 1e3:.0f} ms (median of {self.edges} edges, from {lo * 1e3:+.0f} to "
                f"{hi * 1e3:+.0f} ms)" + (": aligned by that before use" if applied else
                                          "; the hint is used as it came"))


def edge_lag_samples(z, ok, rest, k, lo, hi, max_lag, false_alarm_prob):
    """The shift (samples, > 0: later) of the hint's edge at sample k that minimises the
    excess energy inside its rest, over samples lo … hi − 1; None if they cannot say."""
    seg = slice(lo, hi)
    zs = z[seg]
    good = ok[seg]
    if np.count_nonzero(good) < 8:
        return None
    m = float(np.median(zs[good]))
    mad = float(np.median(np.abs(zs[good] - m)))
    sigma2 = (MAD_TO_SIGMA * mad) ** 2
    if not sigma2 > 0.0:
        return None
    excess = np.where(good, (zs - m) ** 2 - sigma2 * chi2_isf(false_alarm_prob, 1), 0.0)
    cum = np.concatenate(([0.0], np.cumsum(excess)))  # cum[i] = Σ excess[lo … lo + i − 1]
    rest_before = bool(rest[k - 1])  # rest → moving: the rest lies before the edge
    best, best_lag = math.inf, 0
    for lag in range(-max_lag, max_lag + 1):
        b = k + lag - lo  # the shifted edge, relative to lo
        if b < 0 or b > hi - lo:
            continue
        score = cum[b] if rest_before else cum[hi - lo] - cum[b]
        if score < best or (score == best and abs(lag) < abs(best_lag)):
            best, best_lag = score, lag
    return best_lag


def hint_latency(t_s, acc_mps2, valid, hint, false_alarm_prob: float = 1e-4) -> HintLatency:
    """The hint's latency against the accelerometer (see the module docstring). hint: 1 at
    rest, 0 moving, NaN unknown; only edges between two known values count."""
    t = np.asarray(t_s, dtype=float)
    z = np.asarray(acc_mps2, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(z)
    h = np.asarray(hint, dtype=float)
    if t.size < 3:
        return HintLatency(None, 0, ())
    period = float(np.median(np.diff(t)))
    if not period > 0.0:
        return HintLatency(None, 0, ())
    max_lag = max(1, int(round(MAX_LATENCY_S / period)))
    known = np.isfinite(h)
    rest = known & (h >= 0.5)
    edges = np.flatnonzero(known[1:] & known[:-1] & (rest[1:] != rest[:-1])) + 1
    lags = []
    for i, k in enumerate(edges):
        prev_mid = (edges[i - 1] + k + 1) // 2 if i > 0 else 0
        next_mid = (k + edges[i + 1]) // 2 if i + 1 < edges.size else t.size
        lo = max(k - max_lag, prev_mid)
        hi = min(k + max_lag, next_mid)
        lag = edge_lag_samples(z, ok, rest, int(k), int(lo), int(hi), max_lag, false_alarm_prob)
        if lag is not None:
            lags.append(lag * period)
    if len(lags) < MIN_EDGES:
        return HintLatency(None, len(lags), tuple(lags))
    return HintLatency(float(np.median(lags)), len(lags), tuple(lags))


def aligned_hint(t_s, hint, lag_s: float) -> np.ndarray:
    """The hint as the accelerometer's edges have it: each value lag_s later (> 0) or
    earlier than it came; before its first value, its first value."""
    t = np.asarray(t_s, dtype=float)
    h = np.asarray(hint, dtype=float)
    idx = np.searchsorted(t, t - lag_s, side="right") - 1
    out = h[np.clip(idx, 0, h.size - 1)]
    out[idx < 0] = h[0]
    return np.ascontiguousarray(out)
