"""An offline estimate from the whole record: rests found on the accelerometer's own quiet
stretches, a Kalman filter over [position, velocity, bias] with zero-velocity updates at
them, and a Rauch–Tung–Striebel backward pass.

Unlike the realtime filter plus a backward pass, nothing here is decided one sample at a
time: the record is read as a whole, in three phases, each a small function.

1. **Quiet stretches** (`quiet_samples`): a window of W samples (the detector's window,
   `EstimatorSettings.standstill_window_s`) is quiet when its acceleration, the rest level
   removed, moves the velocity by no more than the velocity test can resolve
   (`standstill_speed_floor_mps` / DECISIVE_SIGMAS = 20 mm/s) anywhere inside it — a
   ringing mount swings about the rest level and passes, an acceleration of the machine
   does not — and its mean sits at the rest level within Student's t bound at the
   detector's false-alarm rate p (10⁻⁴ per window) on the recording's own noise σ
   (`sample_noise_std_mps2`: the quiet part of its initial rest, or the sensor model)
   over the window's effective degrees of freedom: a slow steady move is not a rest (an
   offset step reads the same on one axis and is taken for motion). The rest level is
   the median of the means of the windows that pass the
   variance test of a rest (s² ≤ σ²·χ²_ν(1 − p)/ν, the one-axis form of the SHOE / GLRT
   detectors: Skog et al. 2010). Every sample a quiet window covers is quiet (a window
   looks both ways: a rest's first and last samples are covered; at its edges the
   velocity is within the resolution of zero). The shortest candidate is one window.
   The machine's hint vetoes ("moving": no rest there) and never adds a rest the
   accelerometer does not show: a hinted stretch must pass the same tests. (Letting a
   hinted window skip the mean test took in the sensor's settling after a stop — sim
   robot-like with the hint 1.4 % worst move against 0.5 % — and gained nothing on the
   robot files: docs/decisions/0121.)
2. **Which quiet stretches are rests** (`decide_rests`): a cruise is as quiet as a rest.
   At the first sample of each candidate the filter's velocity is tested as the realtime
   detector tests it: a rest is below the floor speed, |v| ≤ floor, and the test decides
   only when the floor is DECISIVE_SIGMAS σ_v (σ_v² the filter's plus the sensitivity's
   share (s·v)²); beyond the floor the candidate is a cruise and is not used in that
   direction. The test runs forward, and backward on the record reversed in time (a
   body's acceleration reads the same backward), each direction with its own earlier
   decisions: the stops are decided from both ends. The forward run starts from the
   record's first quiet stretch taken as a rest (every method assumes a start at rest),
   the backward one from its last (refuted when the forward run calls that a cruise:
   then the backward run decides nothing). A direction that took a rest without
   evidence (σ_v too wide) decides nothing after it. A candidate is used when no
   direction calls it a cruise, or one accepts it and the other calls it a cruise; it is
   decisive when one accepts and none calls it a cruise. Where a used rest is not
   decisive, the position is flagged 256 from the rest before it to the rest after it.
   A record that does not end in a used rest is smoothed both ways — ending at rest
   (v = 0 at its last sample) and not — the first given, flagged from the last decisive
   rest, its variance the larger plus the squared difference: σ covers both answers
   (not `forward_only`: a realtime estimator does not know where the record ends).
3. **Filter and backward pass** (`_forward`, `_rts`): x = [p, v, b], the measured
   acceleration as the input (v̇ = z − b − w), the white noise's density N (velocity
   random walk N²/2), the bias a random walk of strength K (`bias_random_walk_…`: the
   drift fit's or what a 4-hour record of the recording's white noise could have missed)
   plus the drift model's deterministic part; v = 0 at every rest sample with
   `zupt_velocity_std_mps`; then RTS over the stored predictions. A lost or invalid
   stretch is bridged by the mean of its valid neighbours, with one sample's noise as the
   acceleration's σ over it, plus their half-difference when several samples are missing:
   one missing sample of a band-limited sensor lies between its neighbours, and their
   difference in motion is mostly their own noise (counting it let one lost sample take a
   whole move's velocity correction: docs/decisions/0175).

The reported σ adds what the model cannot see, as the realtime filter's: the sensitivity
(σ_s·p)², (σ_s·v)² and the duty cycle's reading instant.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.integration import hold_invalid
from gateway.core.jit import jit
from gateway.core.runs import true_runs

# a candidate's verdict in one direction
CRUISE, ABSTAIN, REST = -1, 0, 1
# the decisive test's power: a stop is told from a cruise at the floor speed only when the
# floor is this many σ_v (as the realtime detector's standstill_velocity_sigmas)
DECISIVE_SIGMAS = 5.0
# a window decides only with this share of valid samples (as the realtime detector)
MIN_VALID_SHARE = 0.8


@dataclass(frozen=True)
class RestDecision:
    """One candidate rest and what each direction's velocity test said of it."""

    start: int
    stop: int  # exclusive
    forward: int  # CRUISE / ABSTAIN / REST
    backward: int

    @property
    def used(self) -> bool:
        """Taken as a rest: no direction calls it a cruise, or the directions disagree
        (then flagged); a cruise both agree on is not."""
        return not (self.forward == CRUISE and self.backward != REST
                    or self.backward == CRUISE and self.forward != REST)

    @property
    def decisive(self) -> bool:
        """Accepted on evidence: one direction accepts and none calls it a cruise."""
        return CRUISE not in (self.forward, self.backward) and REST in (self.forward, self.backward)


# --- phase 1: quiet stretches ---------------------------------------------------------------

def window_stats(acc_mps2, valid, w: int):
    """Per window of w samples starting at each index: valid count, mean, sample variance."""
    ok = np.asarray(valid, dtype=bool)
    z = np.where(ok, acc_mps2, 0.0)
    # centre before squaring: the bias may be a whole g, the noise micro-g
    centre = float(np.median(z[ok])) if ok.any() else 0.0
    zc = np.where(ok, z - centre, 0.0)
    c0 = np.concatenate(([0.0], np.cumsum(ok.astype(float))))
    c1 = np.concatenate(([0.0], np.cumsum(zc)))
    c2 = np.concatenate(([0.0], np.cumsum(zc * zc)))
    cnt = c0[w:] - c0[:-w]
    m = (c1[w:] - c1[:-w]) / np.maximum(cnt, 1.0)
    var = ((c2[w:] - c2[:-w]) - cnt * m * m) / np.maximum(cnt - 1.0, 1.0)
    return cnt, m + centre, np.maximum(var, 0.0)


def rest_level(mean, flat, forward_only: bool) -> np.ndarray:
    """The rest level per window: the median of the flat windows' means (a cruise's mean is
    the rest's too) — over the record, or (`forward_only`) over the windows up to this one;
    NaN before the first flat window (no rest seen yet: nothing can be judged a rest)."""
    if not forward_only:
        level = float(np.median(mean[flat])) if flat.any() else float(np.median(mean))
        return np.full(mean.size, level)
    out = np.empty(mean.size)
    low: list[float] = []  # max-heap (negated) of the lower half, min-heap of the upper half
    high: list[float] = []
    current = math.nan
    for i, (m, f) in enumerate(zip(mean.tolist(), flat.tolist(), strict=True)):
        if f:
            heapq.heappush(low, -heapq.heappushpop(high, m))
            if len(low) > len(high) + 1:
                heapq.heappush(high, -heapq.heappop(low))
            current = -low[0] if len(low) > len(high) else 0.5 * (high[0] - low[0])
        out[i] = current
    return out


def quiet_samples(t_s, acc_mps2, valid, settings: EstimatorSettings, hint=None,
                  forward_only: bool = False) -> np.ndarray:
    """True on every sample a quiet window covers (phase 1): its acceleration, the rest level
    removed, moves the velocity by at most the velocity test's resolution (speed floor /
    DECISIVE_SIGMAS) anywhere inside it, and its mean sits at the rest level within the
    noise's t bound at the detector's false-alarm rate. The machine's "moving" vetoes.
    `forward_only`: the rest level from the windows so far (`rest_level`)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    n = np.size(acc_mps2)
    w = settings.window_samples
    if n < w + 1:
        return np.zeros(n, dtype=bool)
    ok = np.asarray(valid, dtype=bool)
    cnt, mean, var = window_stats(acc_mps2, ok, w)
    flat = (cnt >= MIN_VALID_SHARE * w) & (var <= settings.window_variance_threshold_mps2_sq)
    level = rest_level(mean, flat, forward_only)
    # at each sample, the level known when it arrived: that of the window ending there
    level_at = level[np.clip(np.arange(n) - w + 1, 0, level.size - 1)]
    # (before any rest level: a velocity swing is a difference inside one window, so any
    # finite level there cancels)
    level_at = np.where(np.isfinite(level_at), level_at, 0.0)
    dt = np.empty(n)
    dt[:-1] = np.diff(t_s)
    dt[-1] = dt[-2] if n > 1 else 0.0
    vel = np.concatenate(([0.0], np.cumsum(np.where(ok, acc_mps2 - level_at, 0.0) * dt)))
    # window starting at i: the velocities vel[i+1 … i+w] against vel[i]
    lo = w // 2
    # maximum_filter1d's window at j is j − w//2 … j − w//2 + w − 1: the one starting at i is at i + w//2
    vmax = maximum_filter1d(vel[1:], w)[lo:lo + n - w + 1]
    vmin = minimum_filter1d(vel[1:], w)[lo:lo + n - w + 1]
    swing = np.maximum(vmax - vel[:n - w + 1], vel[:n - w + 1] - vmin)
    resolution = settings.standstill_speed_floor_mps / DECISIVE_SIGMAS
    passing = (cnt >= MIN_VALID_SHARE * w) & (swing <= resolution)
    nu = settings.window_dof
    bound = stdtrit_two_sided(settings.standstill_false_motion_prob, max(nu - 1.0, 1.0))
    passing &= np.abs(mean - level) <= bound * settings.sample_noise_std_mps2 / math.sqrt(nu)
    # every sample a passing window covers (a window looks both ways: a rest's first and
    # last samples are covered; at its edge the velocity is within the resolution of 0)
    cover = np.concatenate(([0], np.cumsum(passing.astype(np.int64))))
    idx = np.arange(n)
    quiet = (cover[np.clip(idx + 1, 0, passing.size)] - cover[np.clip(idx - w + 1, 0, passing.size)]) > 0
    if hint is not None:
        h = np.asarray(hint, dtype=float)
        quiet &= ~(np.isfinite(h) & (h < 0.5))  # the machine's "moving" vetoes
    return quiet


def stdtrit_two_sided(p: float, dof: float) -> float:
    from scipy.special import stdtrit

    return float(stdtrit(dof, 1.0 - 0.5 * p))


# --- the filter (phases 2 and 3) ---------------------------------------------------------

@dataclass(frozen=True)
class FilterModel:
    """The numbers the filter runs on, each from EstimatorSettings (see the module's doc)."""

    q_vel: float  # N²/2: velocity random walk, (m/s)²/s
    q_bias: float  # K²: bias random walk, (m/s²)²/s
    sample_var: float  # one sample's variance at rest, (m/s²)²
    zupt_var: float
    bias_prior_var: float
    speed_prior_var: float  # the velocity before any rest: the machine's speed range
    drift_c1: float
    drift_t: float
    drift_t0: float
    scale_var: float  # σ_s²
    decisive_std_mps: float  # σ_v beyond which a direction abstains
    lag_s: float  # the sensor filter's lag τ (0: not modelled)

    @classmethod
    def of(cls, s: EstimatorSettings) -> FilterModel:
        return cls(s.velocity_noise_density, s.bias_random_walk_mps2_per_rts ** 2, s.sample_noise_std_mps2 ** 2,
                   s.zupt_velocity_std_mps ** 2, s.bias_initial_std_mps2 ** 2, s.restart_speed_std_mps ** 2,
                   s.drift_c1_mps2, s.drift_time_constant_s, s.drift_start_s, s.sensitivity_std_frac ** 2,
                   s.standstill_speed_floor_mps / DECISIVE_SIGMAS, s.sensor_lag_s)

    def as_array(self) -> np.ndarray:
        return np.array([self.q_vel, self.q_bias, self.sample_var, self.zupt_var, self.bias_prior_var,
                         self.speed_prior_var, self.drift_c1, self.drift_t, self.drift_t0, self.scale_var,
                         self.decisive_std_mps, self.lag_s])


# indices of FilterModel.as_array (the compiled loops take one float array)
_QV, _QB, _SV, _ZV, _BP, _VP, _C1, _DT, _D0, _SC, _DEC, _LAG = range(12)


def bridged_input(t_s, acc_mps2, valid, lost_before, sample_var):
    """Per period k → k+1: the acceleration that acts over it and the extra variance of its
    velocity change (an invalid sample or lost samples: the mean of the valid neighbours,
    one sample's noise as its σ over the bridged time, plus their half-difference when more
    than one sample is missing between them)."""
    n = t_s.size
    ok = np.asarray(valid, dtype=bool)
    u = hold_invalid(acc_mps2, ok)
    extra = np.zeros(n)
    if ok.all() and not np.any(lost_before):
        return u, extra
    idx = np.arange(n)
    prev_ok = np.maximum.accumulate(np.where(ok, idx, -1))
    next_ok = np.minimum.accumulate(np.where(ok, idx, n)[::-1])[::-1]
    lo = np.clip(prev_ok, 0, n - 1)
    hi = np.clip(next_ok, 0, n - 1)
    a_lo = np.where(prev_ok >= 0, acc_mps2[lo], acc_mps2[hi] if n else 0.0)
    a_hi = np.where(next_ok < n, acc_mps2[hi], a_lo)
    a_lo = np.where(prev_ok >= 0, a_lo, a_hi)
    a_lo = np.where(np.isfinite(a_lo), a_lo, 0.0)
    a_hi = np.where(np.isfinite(a_hi), a_hi, 0.0)
    # samples missing between the valid neighbours of each period: one missing sample of a
    # band-limited sensor lies between its neighbours (their mean, one sample's noise); the
    # acceleration may change beyond them only over a gap of several (their half-difference)
    lost_sum = np.concatenate(([0], np.cumsum(np.asarray(lost_before, dtype=np.int64)[1:])))
    p_idx = np.where(ok, idx, lo)
    q_idx = np.minimum(np.concatenate((next_ok[1:], [n - 1])), n - 1)
    missing = (q_idx - p_idx - 1) + (lost_sum[q_idx] - lost_sum[p_idx])
    several = missing > 1
    std = np.where(several, 0.5 * np.abs(a_hi - a_lo), 0.0) + math.sqrt(sample_var)
    # the period k → k+1 is bridged when sample k is invalid or samples were lost after it
    lost_after = np.zeros(n, dtype=bool)
    lost_after[:-1] = np.asarray(lost_before)[1:] > 0
    bridged = ~ok | lost_after
    u = np.where(bridged, 0.5 * (a_lo + a_hi), u)
    nxt_ok = np.zeros(n, dtype=bool)
    nxt_ok[:-1] = ok[1:]
    a_next = np.where(nxt_ok, np.roll(acc_mps2, -1), a_hi)
    std_after = np.where(several, 0.5 * np.abs(np.where(np.isfinite(a_next), a_next, 0.0)
                                               - np.where(ok, acc_mps2, a_lo)), 0.0) + math.sqrt(sample_var)
    s = np.where(ok, std_after, std)
    dt = np.zeros(n)
    dt[:-1] = np.diff(t_s)
    extra = np.where(bridged, (s * dt) ** 2, 0.0)
    return u, extra


@jit
def _propagate(x, P, dt, u, ddrift, qv, qb, extra_vv):
    """x, P from one sample to the next: Φ = [[1, dt, −dt²/2], [0, 1, −dt], [0, 0, 1]],
    the continuous-time Q of the white acceleration noise and the bias random walk."""
    h = 0.5 * dt * dt
    a = u - x[2]
    x[0] += x[1] * dt + h * a
    x[1] += a * dt
    x[2] += ddrift
    F = np.array([[1.0, dt, -h], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
    Pn = F @ P @ F.T
    dt2 = dt * dt
    dt3 = dt2 * dt
    Pn[0, 0] += qv * dt3 / 3.0 + qb * dt3 * dt2 / 20.0
    Pn[0, 1] += qv * dt2 / 2.0 + qb * dt2 * dt2 / 8.0
    Pn[1, 0] = Pn[0, 1]
    Pn[1, 1] += qv * dt + qb * dt3 / 3.0 + extra_vv
    Pn[0, 2] += -qb * dt3 / 6.0
    Pn[2, 0] = Pn[0, 2]
    Pn[1, 2] += -qb * dt2 / 2.0
    Pn[2, 1] = Pn[1, 2]
    Pn[2, 2] += qb * dt
    P[:, :] = Pn


@jit
def _zupt(x, P, r, lag, z):
    """The true velocity is zero: v + τ·(z − b) = 0 with variance r. The state's v lags the
    true velocity by τ·(z − b) (the sensor's one-pole filter still settling, τ = its lag;
    the outputs undo it, estimator_kernel.undo_sensor_lag): H = [0, 1, −τ]."""
    ph0 = P[0, 1] - lag * P[0, 2]
    ph1 = P[1, 1] - lag * P[1, 2]
    ph2 = P[2, 1] - lag * P[2, 2]
    s = ph1 - lag * ph2 + r
    y = -(x[1] + lag * (z - x[2]))
    k0 = ph0 / s
    k1 = ph1 / s
    k2 = ph2 / s
    x[0] += k0 * y
    x[1] += k1 * y
    x[2] += k2 * y
    for i in range(3):
        kk = k0 if i == 0 else (k1 if i == 1 else k2)
        for j in range(3):
            hp = ph0 if j == 0 else (ph1 if j == 1 else ph2)
            P[i, j] -= kk * hp
    for i in range(3):
        for j in range(i + 1, 3):
            v = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = v
            P[j, i] = v


@jit
def _drift_step(t0, t1, c1, tc, d0):
    if c1 == 0.0:
        return 0.0
    return c1 * (math.exp(-(t0 + d0) / tc) - math.exp(-(t1 + d0) / tc))


@jit
def _run(t, u, extra, rest, entry_verdict_out, model, store, xs_pred, ps_pred, xs_f, ps_f, gate):
    """The filter over the record: ZUPT on rest samples; with gate, the candidate starting at
    each entry (rest[k] and not rest[k−1]) is judged first by the velocity test and its
    verdict written to entry_verdict_out[k] (a cruise's samples are then not updated).
    With store, the predictions and posteriors go to xs_*/ps_* for the backward pass."""
    n = t.size
    x = np.zeros(3)
    P = np.zeros((3, 3))
    P[1, 1] = model[_VP]
    P[2, 2] = model[_BP]
    skipping = False
    conditional = False  # a rest was taken on no evidence: later verdicts rest on that hypothesis
    for k in range(n):
        if k > 0:
            dt = t[k] - t[k - 1]
            if dt > 0.0:
                _propagate(x, P, dt, u[k - 1], _drift_step(t[k - 1], t[k], model[_C1], model[_DT], model[_D0]),
                           model[_QV], model[_QB], extra[k - 1])
            else:  # time did not advance: nothing propagated, a floor keeps P_pred invertible
                for i in range(3):
                    P[i, i] += 1e-24
        if store:
            xs_pred[k, :] = x
            ps_pred[k, :, :] = P
        if rest[k]:
            entering = k == 0 or not rest[k - 1]
            if entering:
                skipping = False
                if gate:
                    verdict = 1  # the record's first sample: the rest every method assumes
                    if k > 0:
                        # the realtime detector's velocity test: a stop is below the
                        # floor speed, decidable when the floor is DECISIVE_SIGMAS σ_v
                        v = abs(x[1])
                        sd = math.sqrt(P[1, 1] + model[_ZV] + model[_SC] * v * v)
                        if v > model[_DEC] * DECISIVE_SIGMAS:
                            verdict = -1
                            skipping = True
                        elif sd > model[_DEC]:
                            verdict = 0
                    if conditional:
                        verdict = 0
                    elif verdict == 0:
                        conditional = True
                    entry_verdict_out[k] = verdict
            if not skipping:
                _zupt(x, P, model[_ZV], model[_LAG], u[k])
        if store:
            xs_f[k, :] = x
            ps_f[k, :, :] = P


@jit
def _rts(t, xs_pred, ps_pred, xs_f, ps_f, out_x, out_p):
    """Rauch–Tung–Striebel: x_s(k) = x_f(k) + C(x_s(k+1) − x_pred(k+1)), C = P_f Φᵀ P_pred⁻¹."""
    n = t.size
    out_x[n - 1, :] = xs_f[n - 1]
    out_p[n - 1, :, :] = ps_f[n - 1]
    for k in range(n - 2, -1, -1):
        dt = t[k + 1] - t[k]
        if dt < 0.0:
            dt = 0.0
        h = 0.5 * dt * dt
        F = np.array([[1.0, dt, -h], [0.0, 1.0, -dt], [0.0, 0.0, 1.0]])
        C = ps_f[k] @ F.T @ np.linalg.inv(ps_pred[k + 1])
        out_x[k, :] = xs_f[k] + C @ (out_x[k + 1] - xs_pred[k + 1])
        Pk = ps_f[k] + C @ (out_p[k + 1] - ps_pred[k + 1]) @ C.T
        out_p[k, :, :] = 0.5 * (Pk + Pk.T)


# --- phase 2: decisions ------------------------------------------------------------------

def _verdicts(t, u, extra, quiet, model) -> np.ndarray:
    """The velocity test's verdict at each candidate's first sample, one direction."""
    verdict = np.zeros(t.size, dtype=np.int8)
    dummy3, dummy33 = np.empty((1, 3)), np.empty((1, 3, 3))
    _run(t, u, extra, quiet, verdict, model.as_array(), False, dummy3, dummy33, dummy3, dummy33, True)
    return verdict


def decide_rests(t, u, extra, quiet, model: FilterModel, forward_only: bool = False) -> list[RestDecision]:
    """Each quiet stretch judged from both ends (phase 2); `forward_only`: from its start
    alone, as a realtime estimator must (the backward verdict abstains)."""
    fwd = _verdicts(t, u, extra, quiet, model)
    if forward_only:
        return [RestDecision(a, b, int(fwd[a]), ABSTAIN) for a, b in true_runs(quiet)]
    # backward: the record reversed in time; the period k → k+1 is the reversed period
    # n−2−k → n−1−k, so its input and extra variance move by one
    t_back = np.ascontiguousarray(t[-1] - t[::-1])
    u_back = np.ascontiguousarray(np.concatenate((u[-2::-1], [0.0])))
    e_back = np.ascontiguousarray(np.concatenate((extra[-2::-1], [0.0])))
    # the drift model counts time from power-on, forward: not in the backward decision
    back_model = FilterModel(**{**model.__dict__, "drift_c1": 0.0})
    bwd = _verdicts(t_back, u_back, e_back, np.ascontiguousarray(quiet[::-1]), back_model)[::-1]
    runs = true_runs(quiet)
    if runs and runs[-1][1] == t.size and fwd[runs[-1][0]] == CRUISE and runs[-1][0] > 0:
        bwd[:] = ABSTAIN  # the backward run started from a rest the forward one refutes
    decisions = []
    for a, b in runs:
        # the backward run entered this stretch at its last sample
        decisions.append(RestDecision(a, b, int(fwd[a]), int(bwd[b - 1])))
    return decisions


# --- phase 3: the estimate ---------------------------------------------------------------

@dataclass
class ZuptSmoothed:
    """The smoothed estimate and what it decided."""

    pos_m: np.ndarray
    vel_mps: np.ndarray
    bias_mps2: np.ndarray
    pos_var: np.ndarray
    vel_var: np.ndarray
    bias_var: np.ndarray
    rest: np.ndarray  # bool per sample: the rests used
    untrusted: np.ndarray  # bool per sample: a rest the data could not decide lies next to it
    decisions: list[RestDecision]


def smooth(t_s, acc_mps2, valid, lost_before, settings: EstimatorSettings, hint=None,
           forward_only: bool = False) -> ZuptSmoothed:
    """The estimate from the whole record. `forward_only`: what a realtime estimator with
    this detector would publish — each rest decided from its start alone, the forward
    filter's estimate without the backward pass, no assumption that the record ends at
    rest (a quiet window still covers the samples it spans: one window of latency)."""
    t = np.ascontiguousarray(t_s, dtype=float)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(acc_mps2)
    acc = np.where(ok, acc_mps2, 0.0)
    model = FilterModel.of(settings)
    u, extra = bridged_input(t, acc, ok, np.asarray(lost_before), model.sample_var)
    quiet = quiet_samples(t, acc, ok, settings, hint, forward_only)
    decisions = decide_rests(t, u, extra, quiet, model, forward_only)
    n = t.size
    rest = np.zeros(n, dtype=bool)
    untrusted = np.zeros(n, dtype=bool)
    used = [d for d in decisions if d.used]
    for d in used:
        rest[d.start:d.stop] = True
    # the span between the neighbouring rests of an undecided one is flagged
    for i, d in enumerate(used):
        if not d.decisive:
            lo = used[i - 1].stop if i > 0 else 0
            hi = used[i + 1].start if i + 1 < len(used) else n
            untrusted[lo:hi] = True
    if not used:
        untrusted[:] = True
    x, p, v_pred, v_pred_var = _smoothed(t, u, extra, rest, model, not forward_only)
    ended = rest
    if not rest[-1] and not forward_only:
        # the recording does not end in a rest the data confirm: two answers — it ends at
        # rest (v = 0 at its last sample, as every method assumes it starts at rest) or
        # not — and no evidence to choose. The first is given, flagged from the last
        # decisive rest, with a variance that covers both (the larger plus their squared
        # difference). Not `forward_only`: a realtime estimator does not know that the
        # record ends there (assuming it took zupt-forward's worst move on robot ×6 from
        # 39.2 to 10.5 % with knowledge no causal estimator has).
        last = max((d.stop for d in used if d.decisive), default=0)
        ended = rest.copy()
        ended[-1] = True
        x_end, p_end, v_pred, v_pred_var = _smoothed(t, u, extra, ended, model, not forward_only)
        for i in range(3):
            p_end[:, i, i] = np.maximum(p_end[:, i, i], p[:, i, i]) + (x_end[:, i] - x[:, i]) ** 2
        x, p = x_end, p_end
        untrusted[last:] = True
    p[:, 0, 0] += model_error_var(t, x[:, 0], ended, v_pred, v_pred_var, model.scale_var)
    return ZuptSmoothed(x[:, 0].copy(), x[:, 1].copy(), x[:, 2].copy(), p[:, 0, 0].copy(), p[:, 1, 1].copy(),
                        p[:, 2, 2].copy(), rest, untrusted, decisions)


def _smoothed(t, u, extra, rest, model: FilterModel, backward_pass: bool = True):
    """The forward filter with v = 0 on the rest samples, then RTS (unless not
    `backward_pass`): (x, P) per sample."""
    n = t.size
    xs_pred, xs_f = np.empty((n, 3)), np.empty((n, 3))
    ps_pred, ps_f = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    _run(t, u, extra, rest, np.zeros(n, dtype=np.int8), model.as_array(), True, xs_pred, ps_pred, xs_f, ps_f,
         False)
    if backward_pass:
        _rts(t, xs_pred, ps_pred, xs_f, ps_f, xs_f, ps_f)  # in place: RTS reads x_f(k), P_f(k) before writing
    return xs_f, ps_f, xs_pred[:, 1].copy(), ps_pred[:, 1, 1].copy()


def model_error_var(t, pos, rest, v_pred, v_pred_var, scale_var) -> np.ndarray:
    """The position variance the filter's model cannot see, per move between two rests,
    summed from move to move (each move's error is its own):
    - the gain on the move: (σ_s·Δp)², a sensitivity off by s reads each move s·Δp off —
      per move, not on the net position, because a pulse's gain need not be the same for
      every move (a fast high-g move reads short: issue 29, point 6), and a ZUPT cannot see
      it (a symmetric pulse's gain error leaves no velocity at the stop);
    - the velocity found at the move's closing rest beyond what the model predicts,
      e² = max(0, y² − S) (y the forward velocity there, S its predicted variance): a
      velocity error the model did not explain appeared at an unknown time in the move;
      the smoother spreads it as a ramp, the truth may be a step anywhere in it: up to
      e·T/2 in position, taken as its σ.
    Inside a move the term grows with the share of the move's time gone by."""
    n = t.size
    out = np.zeros(n)
    runs = true_runs(rest)
    total = 0.0
    for (_a0, b0), (a1, _b1) in zip(runs[:-1], runs[1:], strict=False):
        dur = t[a1] - t[b0 - 1]
        excess = max(0.0, v_pred[a1] ** 2 - v_pred_var[a1])
        term = scale_var * (pos[a1] - pos[b0 - 1]) ** 2 + excess * dur * dur / 4.0
        if dur > 0.0:
            out[b0:a1] = total + term * (t[b0:a1] - t[b0 - 1]) / dur
        total += term
        out[a1:] = total
    return out
