"""The gateway's estimator, one sample at a time: the numbers only (compiled when numba is there).

Model (continuous time, state x = [p, v, b]):
    the measured acceleration z is the true acceleration plus the bias b plus white
    noise of density N; it drives the state as an input (strapdown form):
        ṗ = v,  v̇ = z − b − w,  ḃ = ḋ(t) + w_b
    d(t) = C1·(1 − e^(−(t + t0)/T)) is the fitted zero drift (deterministic input),
    w has density N²/2 on v, w_b is the bias random walk K².
    Motion:     Φ(Δt) = [[1, Δt, −Δt²/2], [0, 1, −Δt], [0, 0, 1]], Q(Δt) in closed form.
    Standstill: v ≡ 0 and the position is held: Φs = [[1, 0, 0], [0, 0, 0], [0, 0, 1]],
                only the bias random walk enters; every sample is a zero-acceleration
                update z = b + n (ZARU, variance N²/(2·Ts)).
    Entering a standstill: a zero-velocity update v = 0 (ZUPT) — the velocity error the
                motion piled up corrects position and bias through their correlations.
    Hinted at rest, no standstill (a rest shorter than the window, a ringing mount): a
                soft v = 0 to within the velocity swing of the hinted samples, in motion
                (soft_hinted_update) — the same correction through the same correlations, weaker.

Sample k's acceleration is its period's mean (the duty cycle measures the whole
period), so it is integrated over [t_k, t_(k+1)]: step k first propagates the state from
t_(k−1) to t_k with sample k−1's input, then judges sample k (standstill detector),
then applies the updates. The estimate is the state at t_k.

The step keeps everything in preallocated arrays (no allocation per sample) so that the
offline loop compiles with numba; the realtime class calls the same function.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from gateway.core.jit import jit, jit_inline, jit_without_refcounts
from gateway.core.standstill import (
    MIN_WINDOW_SAMPLES,
    hint_gate_open,
    hinted_rest_fits,
    mean_velocity_offset,
    standstill_tests,
    stopping_within_a_window,
    velocity_consistent_with_rest,
    velocity_decidable,
    velocity_swing,
    window_statistics,
)

# ---- parameter layout (EstimatorSettings.kernel_params) -------------------------------
P_QV = 0  # velocity process noise density N²/2
P_QB = 1  # bias random walk K²
P_R = 2  # ZARU variance N²/(2 Ts)
P_DRIFT_C1 = 3
P_DRIFT_T = 4
P_DRIFT_T0 = 5
P_WINDOW = 6
P_VAR_MAX = 7
P_MEAN_SIGMAS = 8
P_VEL_SIGMAS = 9
P_SPEED_FLOOR = 10
P_R_ZUPT = 11
P_MISSING_VAR = 12
P_BIAS0_VAR = 13
P_LAG = 14  # the sensor filter's time constant τ (s): the outputs undo its lag
P_QUIET_STOP_S = 15  # a quiet stretch this long is a stop even when the velocity cannot decide
P_VIBRATION = 16  # a window whose velocity swing stays below this (m/s) is vibration, not motion
P_STEP_MAX = 17  # the largest offset step (m/s²) a rest hint may explain; beyond it the axis moves
P_RESTART_VEL_VAR = 18  # velocity variance (m/s)² after a restart with the axis possibly moving
P_HINT_LATENCY = 19  # how long a machine's "moving" may lead the sensor's motion (s): unknown for that long
P_SCALE_VAR = 20  # the sensitivity's variance (fraction²): the reported σ carries s·p and s·v
P_READING_INSTANT = 21  # S/2g (s²/m) for a duty-cycle part whose reading instant is not known, else 0
P_ZUPT_CHI2 = 22  # χ²₁ quantile at 1 − standstill_false_motion_prob: a stop's velocity beyond it is no chance
N_PARAMS = 23

# ---- misc state layout ----------------------------------------------------------------
M_T_PREV = 0
M_HAVE_PREV = 1
M_U_PREV = 2  # acceleration input held for the next propagation
M_PREV_INVALID = 3  # the held input is stale (sample k−1 was invalid)
M_REGIME = 4
M_ZUPT_INNOV = 5  # velocity innovation at the last standstill entry (m/s)
M_ZUPT_NIS = 6
M_RING_POS = 7
M_RING_FILL = 8
M_COUNT = 9  # samples processed
M_STILL_START = 10  # sample number where the current standstill began
# The machine's own word on the axis, set by the caller before a step (set_hint):
# +1 "at rest", −1 "moving", 0 unknown. Evidence, not an order (hint_gate).
M_HINT = 11
M_HINT_RUN = 12  # consecutive samples with the rest hint (a window of them may contradict it)
M_LAST_STILL_T = 13  # time of the latest standstill sample (start of the current motion)
M_PEAK_SPEED = 14  # largest |v| since the latest standstill: was there a move?
M_STEP_OPEN = 15  # the offset-step hypothesis has been opened in this motion
M_UNTRUSTED = 16  # position not trustworthy: held until a stop is accepted decisively
M_QUIET_T0 = 17  # start of the current undecidable quiet stretch in motion (NaN: none)
M_PERIOD = 18  # the latest sample period (s), for the window's velocity swing
M_HAVE_U = 19  # M_U_PREV holds a valid sample (not only the 0 it starts with)
M_VEL_UNKNOWN = 20  # restarted with the axis possibly moving: the first quiet window is no rest
M_BIAS_REQUESTED = 21  # 1: a re-estimation of the bias was asked for; the next standstill does it
M_LAST_REST_HINT_T = 22  # time of the latest sample hinted "at rest" (−inf: none)
M_QUIET_FROM_V = 23  # velocity where the current quiet stretch in motion began above the floor (NaN: none)
M_QUIET_FROM_T = 24  # and its time
M_READING_DRIFT = 25  # position a modulator reading at its edge would have added since the tare (m)
# Σ (position correction)² of the stops the machine's hint and the integrated accelerometer
# disagreed on (since the tare): the reported σ covers both answers (hint_gate)
M_DISAGREE_VAR = 26
N_MISC = 27

# snapshot ring (one row per sample of the last window): x, P (00 01 02 11 12 22), t,
# and the sample's input: z, valid, lost_before
N_SNAP = 13

UNINITIALISED = 0
MOTION = 1
STANDSTILL = 2

# transition from sample k−1 to k, as the smoother needs it
T_NONE = 0  # nothing propagated (before initialisation, or no time step)
T_MOTION = 1
T_STANDSTILL = 2
T_RESET = 3  # the filter (re)initialised at this sample: no information flows back past it

# ---- per-step output layout -----------------------------------------------------------
O_POS = 0
O_VEL = 1
O_ACC = 2
O_BIAS = 3
O_POS_VAR = 4
O_VEL_VAR = 5
O_BIAS_VAR = 6
O_INNOV = 7  # ZARU innovation z − b⁻ at standstill (m/s²), 0 when no update
O_NIS = 8  # its normalised square y²/S
O_ZUPT_INNOV = 9  # velocity innovation at the latest standstill entry (held)
O_ZUPT_NIS = 10
O_FLAGS = 11
O_TRANSITION = 12
O_ZARU_Y = 13
O_ZARU_S = 14  # 0 when no ZARU at this sample
# the velocity update at this sample — a standstill's ZUPT or a soft hinted one (soft_hinted_update),
# never both — as the smoother needs it
O_ZUPT_Y = 15
O_ZUPT_S = 16  # 0 when no velocity update at this sample
O_ZUPT_K0 = 17
O_ZUPT_K1 = 18
O_ZUPT_K2 = 19
O_ROLLBACK_FROM = 20  # −1, or the sample whose state the filter returned to (roll_back_to_onset)
N_OUT = 21

# ---- health flags ---------------------------------------------------------------------
F_STANDSTILL = 1
F_INITIALISED = 2
F_INPUT_INVALID = 4  # this sample's acceleration was missing, NaN/inf or flagged: held
F_GAP = 8  # samples were lost before this one
F_ENTRY = 16  # a standstill began at this sample (ZUPT applied)
F_UNDECIDED = 32  # too few valid samples in the window to judge: the previous regime is held
F_TIME_ERROR = 64  # the sample time did not increase: not propagated
F_ROLLBACK = 128  # a standstill ended: the zero-acceleration updates of the last window were undone
F_UNTRUSTED = 256  # position not trustworthy now: a quiet stretch may be a cruise or a stop (held until
# a stop is accepted on evidence: the velocity test passing decisively, or the hint)
# "at rest" hinted and the accelerometer disagrees: a whole hinted window shows motion (not obeyed),
# or a hinted stop's velocity is beyond chance (obeyed, position flagged 256, σ covering both answers)
F_HINT_CONFLICT = 512
F_OFFSET_STEP = 1024  # a quiet stretch after a move sits off the bias: the offset may have stepped
F_HINT_REST = 2048  # this sample's standstill was accepted on the machine's hint
F_FAULT = 4096  # the state is not finite or has diverged: the numbers mean nothing (reset it)
F_BIAS_ESTIMATING = 8192  # the bias is not measured yet (before the first standstill, or asked anew)
F_HINT_SOFT = 16384  # in motion, hinted at rest: a soft v = 0 within the hinted samples' swing (soft_hinted_update)

# a velocity beyond this is no motion of any machine the sensor rides on: the filter diverged
DIVERGED_SPEED_MPS = 1000.0


@jit
def drift_at(t_s, prm):
    return prm[P_DRIFT_C1] * -math.expm1(-(t_s + prm[P_DRIFT_T0]) / prm[P_DRIFT_T])


@jit
def undo_sensor_lag(pos, vel, y_edge, lag):
    """The outputs as the true motion had them, from the filter's (lagged) state.

    The sensor's one-pole filter (τ = lag) lags the measured acceleration y behind the
    true u: u = y + τ·ẏ, so ∫u = ∫y + τ·y — the true velocity is v + τ·y and the true
    position p + τ·v, exactly; y_edge is y at the sample's time (the mean of the two
    samples around it, the bias removed). Scalars (the realtime step) or arrays (the
    smoother) alike.
    """
    return pos + lag * vel, vel + lag * y_edge


@jit
def disagreement_var(gain_pos, innovation):
    """A stop taken on the machine's hint against the integrated velocity (beyond chance):
    the position with the stop and without it differ by the update's position correction
    K_p·y; the reported variance adds its square, so that σ covers both answers."""
    d = gain_pos * innovation
    return d * d


@jit
def with_scale_error(var, value, prm):
    """A variance from the filter with the sensitivity's share added: a reading (1 + s)·a
    makes the velocity off by s·v and the position by s·p (p since the tare), a systematic
    error the filter's model does not contain."""
    return var + prm[P_SCALE_VAR] * value * value


@jit
def reading_instant_var(drift_m):
    """The reported position's variance share for a duty-cycle reading whose instant in its
    period is not known (SensorParams.dcm_reading; the data sheet does not say): read at the
    period's mean it adds nothing, read where the duty cycle ends it adds drift_m (the
    position (S·T2/2g)·∫a² dt, of one sign) — so 0 … drift_m, taken as a 2σ bound (as the
    sensitivity's ±1 % is) and not corrected."""
    return 0.25 * drift_m * drift_m


@jit
def add_reading_instant_error(var, acc, t_s, prm):
    """reading_instant_var over a track, in place (the smoothed estimate's memory budget: no
    new array): the drift accumulated through its motion, acc the estimate's acceleration
    (0 at standstill), each sample period its own T2."""
    c = prm[P_READING_INSTANT]
    if c <= 0.0:
        return
    drift = 0.0
    for k in range(1, var.size):
        dt = t_s[k] - t_s[k - 1]
        if dt > 0.0:
            drift += c * dt * acc[k - 1] * acc[k - 1] * dt
        var[k] += reading_instant_var(drift)


@jit
def add_scale_error(var, value, prm):
    """with_scale_error over arrays, in place: no new array (the smoothed estimate's memory
    budget, commands/estimate.SMOOTHED_BYTES_PER_SAMPLE)."""
    for k in range(var.size):
        var[k] = with_scale_error(var[k], value[k], prm)


@jit
def propagate_motion(x, P, dt, u, ddrift, qv, qb, missing_var, missing_dt):
    """x, P from t to t + dt with input u (m/s²) held over the period; Φ(dt)·P·Φ(dt)' + Q(dt)."""
    h = 0.5 * dt * dt
    a = u - x[2]
    x[0] += x[1] * dt + h * a
    x[1] += a * dt
    x[2] += ddrift
    # A = Φ P: only the entries the upper triangle of Φ P Φ' reads (Φ's rows 1 and 2 are
    # [0, 1, -dt] and [0, 0, 1], so A's lower-left entries never enter it)
    a00 = P[0, 0] + dt * P[1, 0] - h * P[2, 0]
    a01 = P[0, 1] + dt * P[1, 1] - h * P[2, 1]
    a02 = P[0, 2] + dt * P[1, 2] - h * P[2, 2]
    a11 = P[1, 1] - dt * P[2, 1]
    a12 = P[1, 2] - dt * P[2, 2]
    a22 = P[2, 2]
    # Φ P Φ' (upper triangle), plus Q of white velocity noise qv and bias random walk qb
    d2 = dt * dt
    d3 = d2 * dt
    p00 = a00 + dt * a01 - h * a02 + qv * d3 / 3.0 + qb * d3 * d2 / 20.0
    p01 = a01 - dt * a02 + qv * d2 / 2.0 + qb * d2 * d2 / 8.0
    p02 = a02 - qb * d3 / 6.0
    p11 = a11 - dt * a12 + qv * dt + qb * d3 / 3.0
    p12 = a12 - qb * d2 / 2.0
    p22 = a22 + qb * dt
    if missing_dt > 0.0:
        # the input was unknown over missing_dt: an unknown constant acceleration error
        gp = 0.5 * missing_dt * missing_dt
        gv = missing_dt
        p00 += missing_var * gp * gp
        p01 += missing_var * gp * gv
        p11 += missing_var * gv * gv
    P[0, 0] = p00
    P[0, 1] = p01
    P[1, 0] = p01
    P[0, 2] = p02
    P[2, 0] = p02
    P[1, 1] = p11
    P[1, 2] = p12
    P[2, 1] = p12
    P[2, 2] = p22


@jit
def propagate_standstill(x, P, dt, ddrift, qb):
    """At rest: v ≡ 0, position held, only the bias moves (drift + random walk)."""
    x[1] = 0.0
    x[2] += ddrift
    for i in range(3):
        P[1, i] = 0.0
        P[i, 1] = 0.0
    P[2, 2] += qb * dt


@jit
def scalar_update(x, P, i, y, R, gain):
    """Update with a measurement of component i (innovation y, noise R); gain receives K. Returns S."""
    S = P[i, i] + R
    for r in range(3):
        gain[r] = P[r, i] / S
    for r in range(3):
        x[r] += gain[r] * y
    # P − K S K' = P − P[:, i] P[i, :] / S, kept exactly symmetric
    c0 = P[0, i]
    c1 = P[1, i]
    c2 = P[2, i]
    P[0, 0] -= c0 * c0 / S
    P[1, 1] -= c1 * c1 / S
    P[2, 2] -= c2 * c2 / S
    v01 = P[0, 1] - c0 * c1 / S
    v02 = P[0, 2] - c0 * c2 / S
    v12 = P[1, 2] - c1 * c2 / S
    P[0, 1] = v01
    P[1, 0] = v01
    P[0, 2] = v02
    P[2, 0] = v02
    P[1, 2] = v12
    P[2, 1] = v12
    # rounding must not leave a negative variance (a state measured exactly has 0)
    for r in range(3):
        if P[r, r] < 0.0:
            P[r, r] = 0.0
    return S


@jit
def rest_velocity_update(x, P, z, ok, lag, target, R, gain):
    """The true velocity is `target` (noise R) — 0 for a stop's ZUPT; for a soft hinted
    update, what the hinted samples' zero mean makes of it. Returns (innovation, its
    variance S).

    The state's v lags the true velocity by τ·y (the sensor's filter still settling,
    y = z − b): a stop while the last of a stroke's acceleration is in the sample must not
    take that for a velocity error."""
    y = target - (x[1] + lag * (z - x[2]) if ok else x[1])
    return y, scalar_update(x, P, 1, y, R, gain)


@jit
def pack_cov(P, row, col):
    """The upper triangle of the symmetric P (00 01 02 11 12 22) into row[col:col + 6]:
    the layout of the rollback snapshots and of the smoother's records."""
    row[col] = P[0, 0]
    row[col + 1] = P[0, 1]
    row[col + 2] = P[0, 2]
    row[col + 3] = P[1, 1]
    row[col + 4] = P[1, 2]
    row[col + 5] = P[2, 2]


@jit
def pack_state(x, P, row, col):
    """x, then P's upper triangle (pack_cov), into row[col:col + 9]."""
    row[col] = x[0]
    row[col + 1] = x[1]
    row[col + 2] = x[2]
    pack_cov(P, row, col + 3)


@jit
def unpack_cov(row, col, P):
    """The symmetric P from its upper triangle at row[col:col + 6] (the inverse of pack_cov)."""
    P[0, 0] = row[col]
    P[0, 1] = row[col + 1]
    P[1, 0] = row[col + 1]
    P[0, 2] = row[col + 2]
    P[2, 0] = row[col + 2]
    P[1, 1] = row[col + 3]
    P[1, 2] = row[col + 4]
    P[2, 1] = row[col + 4]
    P[2, 2] = row[col + 5]


class KernelState(NamedTuple):
    """The filter's whole memory, as a value every caller may hold and pass on.

    Arrays, updated in place by `step` (no allocation per sample: the loop compiles);
    a caller reads the newest estimate in `out` (layout O_*) and never needs anything
    else. `new_state(params)` makes a fresh one.
    """

    x: np.ndarray  # [position m, velocity m/s, bias m/s²]
    P: np.ndarray  # its 3×3 covariance
    misc: np.ndarray  # layout M_*
    ring_z: np.ndarray  # the detector's window: accelerations …
    ring_ok: np.ndarray  # … and whether each was valid
    snap: np.ndarray  # state after each sample of the window, for a rollback (N_SNAP columns)
    gain: np.ndarray  # scratch: the last update's Kalman gain
    out: np.ndarray  # the newest estimate, layout O_*


@jit
def open_offset_step(P, delta, since_s):
    """Widen P for an offset step of size delta at an unknown time in the last since_s.

    A step Δ at time s before now leaves the errors (truth − estimate) Δ·g with
    g = (−s²/2, −s, 1) in (p, v, b); with s uniform over [0, since_s] the added
    covariance is Δ²·E[g gᵀ], E[s^k] = since_s^k/(k + 1) — positive semidefinite by
    construction, so the next updates share the correction by these correlations."""
    d2 = delta * delta
    T = max(since_s, 0.0)
    T2 = T * T
    pp = d2 * T2 * T2 / 20.0
    pv = d2 * T2 * T / 8.0
    pb = -d2 * T2 / 6.0
    vv = d2 * T2 / 3.0
    vb = -d2 * T / 2.0
    P[0, 0] += pp
    P[0, 1] += pv
    P[1, 0] += pv
    P[0, 2] += pb
    P[2, 0] += pb
    P[1, 1] += vv
    P[1, 2] += vb
    P[2, 1] += vb
    P[2, 2] += d2


def mark_velocity_unknown(state: KernelState) -> None:
    """After a restart or a board reset mid-operation (fresh state): the axis may be moving,
    so the first quiet window is not taken as a rest (judge_standstill). The position is not
    trustworthy from the first sample on, not only once that window is full: while the
    window fills, the axis may be moving (cleared where a stop is accepted on evidence)."""
    state.misc[M_VEL_UNKNOWN] = 1.0
    state.misc[M_UNTRUSTED] = 1.0


@jit
def hint_code(hint):
    """A recording's or a wire's hint (1 at rest, 0 moving, NaN unknown) → M_HINT's +1/−1/0."""
    if hint != hint:  # NaN (the one value not equal to itself)
        return 0.0
    return 1.0 if hint >= 0.5 else -1.0


def set_hint(state: KernelState, hint) -> None:
    """The machine's standstill hint for the next step: 1 at rest, 0 moving, None/NaN unknown.
    It stays until set again (a wire's timeout is the caller's: set None when it expires)."""
    state.misc[M_HINT] = hint_code(math.nan if hint is None else float(hint))


class StandstillDecision(NamedTuple):
    """What the standstill judgement of one sample tested and what it decided (judge_standstill).

    The seam between the detector and the filter: the update phase reads only this record.
    The statistics are the window's (the last standstill_window_s ending at this sample);
    each test's bound is in the settings (estimator_settings: its principle beside it)."""

    decided: bool  # a full window, ≥ 80 % of it valid, ending in a valid sample: judged
    regime: int  # the regime after this sample: UNINITIALISED, MOTION or STANDSTILL
    n_valid: int  # valid samples in the window
    window_mean: float  # their mean acceleration (m/s²)
    window_var: float  # their sample variance ((m/s²)²), as measured
    variance_threshold: float  # the variance test's bound σ²·χ²_ν(1 − p)/ν
    variance_ok: bool  # the variance test passed (or the window is a vibration within the allowance)
    mean_ok: bool  # the window's mean sits at the bias
    velocity_ok: bool  # the filter's velocity is below the floor, decidably
    velocity_decidable: bool  # 5σ_v ≤ the floor: a stop can be told from a cruise at the floor speed
    trusted_entry: bool  # a stop accepted on evidence (clears the untrusted flag)
    hint_disagrees: bool  # a stop taken on the machine's hint against the integrated velocity
    zaru_ok: bool  # the window is the bias plus noise: a zero-acceleration update is valid
    hint: float  # the machine's word as taken: +1 at rest, −1 moving, 0 unknown (or inside its latency)
    flags: int  # the health flags this judgement raised
    transition: int  # T_RESET when a restart's first quiet window started the filter, else T_NONE


class UpdateRecord(NamedTuple):
    """The measurement updates of one sample (apply_updates, soft_hinted_update): what the
    smoother replays. A velocity update is a standstill's ZUPT or a soft hinted one, never both."""

    zaru_innovation: float  # z − b⁻ at standstill (m/s²), 0 when no update
    zaru_var: float  # its variance S, 0 when no zero-acceleration update
    zupt_innovation: float  # the velocity update's innovation (m/s)
    zupt_var: float  # its variance S, 0 when no velocity update
    gain_p: float  # the velocity update's Kalman gain (position, velocity, bias)
    gain_v: float
    gain_b: float
    flags: int
    transition: int


@jit_inline
def propagate(x, P, m, prm, t_s, z, ok, lost_before, regime_prev):
    """Phase 1: the state from the previous sample's time to t_s, driven by the previous
    sample's acceleration. Returns (flags, transition, the regime it was propagated in)."""
    flags = 0
    transition = T_NONE
    if m[M_HAVE_PREV] == 0.0:
        m[M_T_PREV] = t_s
        m[M_HAVE_PREV] = 1.0
        return flags, transition, regime_prev
    dt = t_s - m[M_T_PREV]
    if not (dt > 0.0):  # also NaN
        flags |= F_TIME_ERROR
        dt = 0.0
    if lost_before > 0:
        flags |= F_GAP
    if dt > 0.0:
        t_prev = m[M_T_PREV]
        ddrift = drift_at(t_s, prm) - drift_at(t_prev, prm)
        if regime_prev == STANDSTILL and lost_before > 0:
            # Samples lost at rest: the axis may have started moving in the gap. Not
            # held: propagated as motion (bridged between the samples either side, so
            # a start inside the gap shows as uncertainty), and the stop must be found
            # again by the detector.
            regime_prev = MOTION
        if regime_prev == MOTION:
            u = m[M_U_PREV]
            missing_var = prm[P_MISSING_VAR]
            if m[M_PREV_INVALID] > 0.0:
                missing_dt = dt
            elif lost_before > 0:
                missing_dt = dt * lost_before / (lost_before + 1.0)
            else:
                missing_dt = 0.0
            if missing_dt > 0.0 and ok and m[M_HAVE_U] > 0.0:
                # The sensor's own low-pass keeps the acceleration of a lost or invalid
                # stretch between the valid samples on either side: take their mean over
                # it, with half their difference (and one sample's noise) as its
                # uncertainty — a stretch across a change of acceleration is as
                # uncertain as the change. Inside a longer outage (this sample invalid
                # too) nothing bounds it: the full range (P_MISSING_VAR).
                half = 0.5 * (z - u)
                u += half * missing_dt / dt
                missing_var = half * half + prm[P_R]
            propagate_motion(x, P, dt, u, ddrift, prm[P_QV], prm[P_QB], missing_var, missing_dt)
            if prm[P_READING_INSTANT] > 0.0 and m[M_PERIOD] > 0.0:
                a = u - x[2]
                m[M_READING_DRIFT] += prm[P_READING_INSTANT] * m[M_PERIOD] * a * a * dt
            transition = T_MOTION
        elif regime_prev == STANDSTILL:
            propagate_standstill(x, P, dt, ddrift, prm[P_QB])
            transition = T_STANDSTILL
        m[M_T_PREV] = t_s
        if lost_before == 0:
            m[M_PERIOD] = dt
    return flags, transition, regime_prev


@jit_inline
def window_of(x, P, m, ring_z, ring_ok, prm, z, ok, regime_prev):
    """This sample into the detector's ring; the window's (valid samples, mean, variance as
    measured, variance as the variance test takes it, vibrating, samples in the ring).

    A vibrating mount is not motion: a window that fails the variance test but whose
    acceleration (the bias removed) swings the velocity by no more than the vibration
    allowance is taken as passing it (its variance := the threshold)."""
    w = int(prm[P_WINDOW])
    pos = int(m[M_RING_POS])
    ring_z[pos] = z if ok else 0.0
    ring_ok[pos] = 1.0 if ok else 0.0
    m[M_RING_POS] = (pos + 1) % w
    fill = min(int(m[M_RING_FILL]) + 1, w)
    m[M_RING_FILL] = fill
    # the window: slots 0 … fill − 1 (the ring fills from slot 0; once full, all of it)
    n_valid, mean, var_raw = window_statistics(ring_z, ring_ok, 0, fill)
    var = var_raw
    vibrating = False
    # (not worth its loop while the filter decisively moves above the floor: no stop follows)
    if regime_prev != UNINITIALISED and fill >= w and n_valid >= 2 and var > prm[P_VAR_MAX] and (
            regime_prev == STANDSTILL or abs(x[1]) <= prm[P_SPEED_FLOOR] or m[M_HINT] > 0.0
            or not velocity_decidable(P[1, 1], prm[P_VEL_SIGMAS], prm[P_SPEED_FLOOR])):
        swing = velocity_swing(ring_z, ring_ok, (pos + 1) % w, w, x[2], m[M_PERIOD])
        if swing <= prm[P_VIBRATION]:
            var = prm[P_VAR_MAX]
            vibrating = True
    return n_valid, mean, var_raw, var, vibrating, fill


@jit_inline
def hint_as_taken(m, prm, t_s):
    """The machine's word for this sample (+1 at rest, −1 moving, 0 unknown), its run of
    "at rest" samples counted. The machine says "moving" as it commands the move; the axis
    (and the sensor, on its own clock) follows a PLC cycle, a fieldbus and a servo later:
    for hint_latency_s after "at rest" the word is no veto on a stop the accelerometer shows."""
    hint = m[M_HINT]
    if hint > 0.0:
        m[M_HINT_RUN] += 1.0
        m[M_LAST_REST_HINT_T] = t_s
    else:
        m[M_HINT_RUN] = 0.0
        if hint < 0.0 and t_s - m[M_LAST_REST_HINT_T] < prm[P_HINT_LATENCY]:
            hint = 0.0
    return hint


@jit_inline
def window_tests(x, P, prm, initialised, n_valid, mean, var):
    """standstill_tests on this window against the filter's velocity and bias."""
    return standstill_tests(initialised, n_valid, mean, var, x[1], P[1, 1], x[2], P[2, 2], prm[P_VAR_MAX],
                            prm[P_R], prm[P_MEAN_SIGMAS], prm[P_VEL_SIGMAS], prm[P_SPEED_FLOOR])


@jit_inline
def offset_step_hypotheses(x, P, m, prm, t_s, regime_prev, hint, n_valid, mean, var, vibrating,
                           var_ok, mean_ok, vel_ok, decidable, still):
    """The two ways a quiet stretch after a move says the offset may have stepped; each opens
    the step hypothesis in the covariance (open_offset_step), once per motion, and the tests
    run again. Returns (var_ok, mean_ok, vel_ok, decidable, still, trusted_entry, flags).

    - A window quiet on the noise alone (no vibration, no end of a deceleration in it) but
      off the bias by no more than an offset step (P_STEP_MAX) after a move: believed when
      the machine says it stands (over a whole window inside the hinted rest), or after a
      move above the speed floor (the filter's velocity may already be off by the step) —
      there "stopped at a new offset" and "accelerating slowly at the old one" are the same
      signal: the hypothesis costs only uncertainty if it is wrong. A stop accepted
      afterwards (hint, or the velocity test if it can still decide) puts the correction
      where it belongs through its ZUPT and ZARU.
    - A stop needs a deceleration the sensor sees. A quiet stretch (variance and mean tests
      passing) that began with the filter above the speed floor is a cruise at constant
      speed; if the filter's velocity falls to a "stop" inside it, no deceleration brought
      it there — the bias it integrates is off (an offset step too small for one window's
      mean, e.g. 5 mg under 10 mg of per-sample noise). Not a stop: the step hypothesis
      opens with the drift's size, Δv over the stretch's time, so the velocity becomes
      undecidable instead of zeroed (flag 256). Only the machine's rest hint may still call
      it a stop (its own checks follow)."""
    flags = 0
    trusted_entry = still
    w = int(prm[P_WINDOW])
    floor = prm[P_SPEED_FLOOR]
    off_by_a_step = var_ok and not vibrating and not mean_ok and abs(mean - x[2]) <= prm[P_STEP_MAX] + \
        prm[P_MEAN_SIGMAS] * math.sqrt(prm[P_R] / max(n_valid, 1) + P[2, 2])
    if regime_prev == MOTION and off_by_a_step and m[M_STEP_OPEN] == 0.0 and (
            (hint > 0.0 and m[M_HINT_RUN] >= w) or m[M_PEAK_SPEED] > floor):
        open_offset_step(P, mean - x[2], t_s - m[M_LAST_STILL_T])
        m[M_STEP_OPEN] = 1.0
        m[M_UNTRUSTED] = 1.0
        flags |= F_OFFSET_STEP
        var_ok, mean_ok, vel_ok, decidable = window_tests(x, P, prm, True, n_valid, mean, var)
        still = var_ok and mean_ok and vel_ok
        trusted_entry = still
    if regime_prev != MOTION or not (var_ok and mean_ok):
        m[M_QUIET_FROM_V] = math.nan
    elif math.isnan(m[M_QUIET_FROM_V]):
        if abs(x[1]) > floor:
            m[M_QUIET_FROM_V] = x[1]
            m[M_QUIET_FROM_T] = t_s
    elif still:
        if m[M_STEP_OPEN] == 0.0:
            span = max(t_s - m[M_QUIET_FROM_T], w * m[M_PERIOD])
            open_offset_step(P, (m[M_QUIET_FROM_V] - x[1]) / span, t_s - m[M_LAST_STILL_T])
            m[M_STEP_OPEN] = 1.0
            flags |= F_OFFSET_STEP
            var_ok, mean_ok, vel_ok, decidable = window_tests(x, P, prm, True, n_valid, mean, var)
        m[M_UNTRUSTED] = 1.0
        still = False
        trusted_entry = False
    return var_ok, mean_ok, vel_ok, decidable, still, trusted_entry, flags


@jit_inline
def hint_gate(x, P, m, prm, z, ok, regime_prev, hint, n_valid, mean, var_raw, still, trusted_entry):
    """The machine's "at rest" is a gate, not an order (hint_gate_open): obeyed once a whole
    window lies inside the hinted rest and the accelerometer agrees there; "moving" forbids
    a stop. Returns (still, trusted_entry, disagrees, zaru_ok, flags)."""
    flags = 0
    disagrees = False
    zaru_ok = True
    if hint > 0.0:
        if hint_gate_open(m[M_HINT_RUN], int(prm[P_WINDOW]), n_valid, mean, var_raw, x[2], P[2, 2], prm[P_R],
                          prm[P_MEAN_SIGMAS]):
            if not still:
                flags |= F_HINT_REST
            still = True
            trusted_entry = True
            # a hinted rest over a ringing mount: v = 0, but its samples are not the bias
            # plus noise (the variance test fails): no zero-acceleration update there
            zaru_ok = var_raw <= prm[P_VAR_MAX]
            if regime_prev == MOTION and not velocity_consistent_with_rest(
                    x[1] + (prm[P_LAG] * (z - x[2]) if ok else 0.0), P[1, 1], prm[P_SCALE_VAR],
                    prm[P_R_ZUPT], prm[P_ZUPT_CHI2]):
                # the machine and the integrated accelerometer disagree beyond chance: the
                # stop is taken (the machine knows where its axis stands), the position is
                # flagged until a stop both agree on
                flags |= F_HINT_CONFLICT
                trusted_entry = False
                disagrees = True
                m[M_UNTRUSTED] = 1.0
        elif m[M_HINT_RUN] >= prm[P_WINDOW]:
            flags |= F_HINT_CONFLICT  # a whole window inside the hinted rest shows motion
    elif hint < 0.0:
        still = False  # "moving": not even the reference point
        trusted_entry = False
    return still, trusted_entry, disagrees, zaru_ok, flags


@jit_inline
def undecidable_quiet(x, m, prm, t_s, regime_prev, hint, mean, vibrating, var_ok, mean_ok, decidable, still):
    """What a quiet stretch in motion that no test accepts as a stop makes of the position.
    Returns (still, flags).

    - the velocity test cannot decide (the filter lost its velocity: a gap, an outage, a
      long time since the latest stop): a stop only once the stretch has lasted longer than
      any cruise of the machine (P_QUIET_STOP_S); the position untrusted;
    - quiet, off the bias (beyond any step), slow, after a move: not a stop we can accept
      (flag 1024, untrusted) — unless it is the last part of a deceleration into a stop, as
      quiet in variance and as far off the bias (stopping_within_a_window)."""
    flags = 0
    floor = prm[P_SPEED_FLOOR]
    if regime_prev == MOTION and not still and var_ok and mean_ok and not decidable and hint >= 0.0:
        if math.isnan(m[M_QUIET_T0]):
            m[M_QUIET_T0] = t_s
        elif t_s - m[M_QUIET_T0] >= prm[P_QUIET_STOP_S]:
            still = True
    else:
        m[M_QUIET_T0] = math.nan
    if regime_prev == MOTION and not still and var_ok and not decidable:
        m[M_UNTRUSTED] = 1.0
    stopping = stopping_within_a_window(mean - x[2], x[1], prm[P_WINDOW] * m[M_PERIOD])
    if regime_prev == MOTION and not still and not vibrating and var_ok and not mean_ok and not stopping \
            and abs(x[1]) <= floor and m[M_PEAK_SPEED] > floor:
        m[M_UNTRUSTED] = 1.0
        flags |= F_OFFSET_STEP
    return still, flags


@jit_inline
def start_moving_after_restart(x, P, m, prm, t_s, mean, n_valid):
    """Restarted (board reset, daemon restart) with the axis possibly moving: a quiet window
    is a rest or a cruise. Its mean is the bias either way; the velocity is unknown within
    the machine's speed. Start in motion, position not trustworthy, until a stop is
    recognised on evidence (the velocity test cannot pass yet)."""
    x[0] = 0.0
    x[1] = 0.0
    x[2] = mean
    for i in range(3):
        for j in range(3):
            P[i, j] = 0.0
    P[1, 1] = prm[P_RESTART_VEL_VAR]
    P[2, 2] = prm[P_R] / n_valid
    m[M_VEL_UNKNOWN] = 0.0
    m[M_UNTRUSTED] = 1.0
    m[M_LAST_STILL_T] = t_s
    m[M_PEAK_SPEED] = 0.0


@jit_inline
def judge_standstill(x, P, m, ring_z, ring_ok, prm, t_s, z, ok, regime_prev):
    """Phase 2: the standstill detector on the window ending with this sample (see
    gateway/core/standstill.py for its tests and their principles). Returns a
    StandstillDecision; changes the state only where a hypothesis widens the covariance
    (an offset step), a restart starts the filter, or the bookkeeping of the hint, the
    quiet stretches and the untrusted flag moves on."""
    flags = 0 if ok else F_INPUT_INVALID
    transition = T_NONE
    w = int(prm[P_WINDOW])
    n_valid, mean, var_raw, var, vibrating, fill = window_of(x, P, m, ring_z, ring_ok, prm, z, ok, regime_prev)
    decided = ok and fill >= w and n_valid * 10 >= w * 8
    regime = regime_prev
    hint = hint_as_taken(m, prm, t_s)
    if regime_prev == MOTION:
        m[M_PEAK_SPEED] = max(m[M_PEAK_SPEED], abs(x[1]))
    var_ok = False
    mean_ok = False
    vel_ok = False
    decidable = velocity_decidable(P[1, 1], prm[P_VEL_SIGMAS], prm[P_SPEED_FLOOR])
    trusted_entry = False
    disagrees = False
    zaru_ok = True
    if decided:
        initialised = regime_prev != UNINITIALISED
        var_ok, mean_ok, vel_ok, decidable = window_tests(x, P, prm, initialised, n_valid, mean, var)
        if vibrating and regime_prev == MOTION and abs(x[1]) > prm[P_VEL_SIGMAS] * math.sqrt(max(P[1, 1], 0.0)):
            # a window that is quiet only as a vibration enters a standstill only if the
            # filter's velocity is zero within its own uncertainty (not merely below the
            # floor): the turn of a slow motion swings the velocity little, too
            vel_ok = False
        still = var_ok and mean_ok and vel_ok
        var_ok, mean_ok, vel_ok, decidable, still, trusted_entry, f = offset_step_hypotheses(
            x, P, m, prm, t_s, regime_prev, hint, n_valid, mean, var, vibrating, var_ok, mean_ok, vel_ok, decidable,
            still)
        flags |= f
        still, trusted_entry, disagrees, zaru_ok, f = hint_gate(x, P, m, prm, z, ok, regime_prev, hint, n_valid,
                                                                mean, var_raw, still, trusted_entry)
        flags |= f
        still, f = undecidable_quiet(x, m, prm, t_s, regime_prev, hint, mean, vibrating, var_ok, mean_ok,
                                     decidable, still)
        flags |= f
        if still and not initialised and m[M_VEL_UNKNOWN] > 0.0 and hint <= 0.0:
            start_moving_after_restart(x, P, m, prm, t_s, mean, n_valid)
            transition = T_RESET
            regime = MOTION
        elif still:
            regime = STANDSTILL
        elif initialised:
            regime = MOTION
    else:
        flags |= F_UNDECIDED
    if regime == MOTION and not velocity_decidable(P[1, 1], prm[P_VEL_SIGMAS], prm[P_SPEED_FLOOR]):
        m[M_UNTRUSTED] = 1.0  # the velocity is no longer known well enough to recognise a stop
    return StandstillDecision(decided, regime, n_valid, mean, var_raw, prm[P_VAR_MAX], var_ok, mean_ok, vel_ok,
                              decidable, trusted_entry, disagrees, zaru_ok, hint, flags, transition)


@jit_inline
def roll_back_to_onset(x, P, m, snap, prm, t_s, z, lost_before, count):
    """Phase 2b. Leaving a standstill: the motion began somewhere in the window that just
    failed. A sharp start fails the tests on its first sample; a gentle one is seen late,
    after the zero-acceleration updates took part of it for bias and the position hold lost
    it. The onset is the change point of the window's mean: the sample i maximising
    |Σ_(i..k) (z − b)|/√n (the likelihood ratio of a mean shift at i), b the bias before
    the window. If it is earlier than this sample, return to the state just before it and
    run the samples since again as motion; their snapshots become motion states. Returns
    the sample whose state the filter returned to, or −1."""
    w = int(prm[P_WINDOW])
    first = max(count - w, int(m[M_STILL_START])) + 1
    b_ref = snap[(first - 1) % w, 2]
    onset = count
    best = abs(z - b_ref)
    acc_sum = 0.0
    n_sum = 0
    for i in range(count, first - 1, -1):
        if i == count:
            acc_sum += z - b_ref
            n_sum += 1
        elif snap[i % w, 11] > 0.0:
            acc_sum += snap[i % w, 10] - b_ref
            n_sum += 1
        score = abs(acc_sum) / math.sqrt(n_sum)
        if score > best:
            best = score
            onset = i
    # a start that ramps up (the sensor's own filter) shows first as a small deviation
    # the change-point score passes over: take in the samples just before the onset
    # that already deviate the same way by more than 3 noise σ
    shift = z - b_ref
    step_sigma = 3.0 * math.sqrt(prm[P_VAR_MAX])
    while onset - 1 >= first:
        j = (onset - 1) % w
        if snap[j, 11] > 0.0 and (snap[j, 10] - b_ref) * shift > 0.0 and abs(snap[j, 10] - b_ref) > step_sigma:
            onset -= 1
        else:
            break
    if onset >= count:
        return -1
    s = onset - 1
    j = s % w
    x[0] = snap[j, 0]
    x[1] = snap[j, 1]
    x[2] = snap[j, 2]
    unpack_cov(snap[j], 3, P)
    t_before = snap[j, 9]
    u = snap[j, 10]
    u_stale = snap[j, 11] == 0.0
    for i in range(s + 1, count + 1):
        ji = i % w
        if i < count:
            t_i = snap[ji, 9]
            lost_i = int(snap[ji, 12])
        else:
            t_i = t_s
            lost_i = lost_before
        dt_i = t_i - t_before
        if dt_i > 0.0:
            if u_stale:
                missing_dt = dt_i
            elif lost_i > 0:
                missing_dt = dt_i * lost_i / (lost_i + 1.0)
            else:
                missing_dt = 0.0
            propagate_motion(x, P, dt_i, u, drift_at(t_i, prm) - drift_at(t_before, prm), prm[P_QV],
                             prm[P_QB], prm[P_MISSING_VAR], missing_dt)
            t_before = t_i
        if i < count:
            pack_state(x, P, snap[ji], 0)
            if snap[ji, 11] > 0.0:
                u = snap[ji, 10]
                u_stale = False
            else:
                u_stale = True
    return s


@jit_inline
def apply_updates(x, P, m, gain, prm, t_s, z, ok, d, regime_prev, count):
    """Phase 3: the updates a standstill brings — the reference point (the filter starts
    here), the ZUPT on entering it, the ZARU on every sample of it. Returns an UpdateRecord."""
    flags = 0
    transition = T_NONE
    zaru_y = 0.0
    zaru_s = 0.0
    zupt_y = 0.0
    zupt_s = 0.0
    gain[0] = 0.0
    gain[1] = 0.0
    gain[2] = 0.0
    if d.decided and d.regime == STANDSTILL:
        if regime_prev == UNINITIALISED:
            # the reference point: the origin here, at rest, bias unknown
            x[0] = 0.0
            x[1] = 0.0
            x[2] = 0.0
            for i in range(3):
                for j in range(3):
                    P[i, j] = 0.0
            P[2, 2] = prm[P_BIAS0_VAR]
            transition = T_RESET
        elif regime_prev == MOTION:
            zupt_y, zupt_s = rest_velocity_update(x, P, z, ok, prm[P_LAG], 0.0, prm[P_R_ZUPT], gain)
            m[M_ZUPT_INNOV] = zupt_y
            m[M_ZUPT_NIS] = zupt_y * zupt_y / zupt_s
            m[M_BIAS_REQUESTED] = 0.0  # this standstill measures the bias anew
            if d.hint_disagrees:
                # the two answers — the hint's stop and the integrated motion — differ by the
                # position this update moved: the reported σ covers both (disagreement_var)
                m[M_DISAGREE_VAR] += disagreement_var(gain[0], zupt_y)
            flags |= F_ENTRY
            if d.hint > 0.0:
                # entered while the machine says "at rest": the hint's stop, whether its gate
                # opened it or its soft update (soft_hinted_update) made the velocity test decide it
                flags |= F_HINT_REST
        k0 = gain[0]
        k1 = gain[1]
        k2 = gain[2]
        if d.zaru_ok:
            zaru_y = z - x[2]
            zaru_s = scalar_update(x, P, 2, zaru_y, prm[P_R], gain)
        if regime_prev != STANDSTILL:
            m[M_STILL_START] = count
            if regime_prev == UNINITIALISED or d.trusted_entry:
                m[M_UNTRUSTED] = 0.0
        m[M_LAST_STILL_T] = t_s
        m[M_PEAK_SPEED] = 0.0
        m[M_STEP_OPEN] = 0.0
        return UpdateRecord(zaru_y, zaru_s, zupt_y, zupt_s, k0, k1, k2, flags, transition)
    return UpdateRecord(zaru_y, zaru_s, zupt_y, zupt_s, 0.0, 0.0, 0.0, flags, transition)


@jit_inline
def soft_hinted_update(x, P, m, ring_z, ring_ok, gain, prm, z, ok, d):
    """Phase 3c. Hinted at rest, yet no standstill: the rest is shorter than the window, or
    the mount rings after the stop (a swing above the vibration allowance fails the variance
    test). The machine's word still says the axis stands: the sensor's velocity over the
    hinted samples swings about zero (a ringing mount), its *mean* is zero. The velocity at
    each sample's start is known from the acceleration before it (bias removed) up to one
    constant, so "mean v = 0" says v_now = v_now − mean v (mean_velocity_offset) — to within
    half the velocity's range over them (a partial period of the ringing need not average
    out; at least zupt_velocity_std_mps): a soft update through the same covariance as a
    ZUPT, so the position is corrected by its correlation with the velocity; the regime
    stays motion (the full-window hinted standstill is the gate's).
    - from MIN_WINDOW_SAMPLES hinted samples (a swing, and a mean judged against its
      spread, need them; the first may still hold the end of a deceleration, which the
      swing then carries) to a window of them: from there the detector judges the hinted
      rest itself (the hinted standstill, or flag 512), and the looks stay bounded, in
      information and in the smoother's records (at most a window's per hinted rest);
    - not when contradicted: the filter decisively knows it moves above the floor (a
      cruise, as for the hinted standstill), or the hinted samples show an acceleration
      of the machine (hinted_rest_fits: mean off the bias beyond an offset step and
      their spread, or a swing beyond the floor);
    - the k-th look at the same rest shares its error with the others (one mount's
      ringing, the samples correlated): it counts with k·σ², so the looks weigh
      together as ~ln k + 0.6 measurements of that σ, not as k independent ones.
    Returns (applied, innovation, its variance S); the gain is in `gain`."""
    w = int(prm[P_WINDOW])
    floor = prm[P_SPEED_FLOOR]
    hint_run = int(m[M_HINT_RUN])
    if not (d.regime == MOTION and d.hint > 0.0 and MIN_WINDOW_SAMPLES <= hint_run <= w) or (
            velocity_decidable(P[1, 1], prm[P_VEL_SIGMAS], floor) and abs(x[1]) > floor):
        return False, 0.0, 0.0
    n_hinted = min(hint_run, int(m[M_RING_FILL]))
    oldest = (int(m[M_RING_POS]) - n_hinted + w) % w
    if not hinted_rest_fits(ring_z, ring_ok, oldest, n_hinted, x[2], P[2, 2], prm[P_R], prm[P_STEP_MAX],
                            prm[P_MEAN_SIGMAS], floor, m[M_PERIOD]):
        return False, 0.0, 0.0
    looks = hint_run - MIN_WINDOW_SAMPLES + 1
    offset, half_range = mean_velocity_offset(ring_z, ring_ok, oldest, n_hinted, x[2], m[M_PERIOD])
    y, s = rest_velocity_update(x, P, z, ok, prm[P_LAG], offset,
                                looks * max(half_range * half_range, prm[P_R_ZUPT]), gain)
    return True, y, s


@jit_inline
def remember_sample(x, P, m, snap, z, ok, lost_before, count, regime):
    """Phase 4: the state after this sample into the window's snapshots (for a later
    rollback), this sample's acceleration held as the next period's input. Returns the
    input held before (the lag correction reads both)."""
    j = count % snap.shape[0]
    pack_state(x, P, snap[j], 0)
    snap[j, 9] = m[M_T_PREV]
    snap[j, 10] = z if ok else 0.0
    snap[j, 11] = 1.0 if ok else 0.0
    snap[j, 12] = lost_before
    m[M_COUNT] = count + 1
    u_before = m[M_U_PREV]
    if ok:
        m[M_U_PREV] = z
        m[M_PREV_INVALID] = 0.0
        m[M_HAVE_U] = 1.0
    else:
        m[M_PREV_INVALID] = 1.0
    m[M_REGIME] = regime
    return u_before


@jit_inline
def write_estimate(x, P, m, out, prm, regime, regime_prev, u_before, flags, upd, rollback_from):
    """Phase 5: the estimate at this sample into state.out (layout O_*): the state with the
    sensor's lag undone, the reported variances with what the model cannot see, the
    health flags."""
    if regime == UNINITIALISED:
        out[O_POS] = 0.0
        out[O_VEL] = 0.0
        out[O_ACC] = 0.0
        out[O_BIAS] = 0.0
        out[O_POS_VAR] = 0.0
        out[O_VEL_VAR] = 0.0
        out[O_BIAS_VAR] = prm[P_BIAS0_VAR]
    else:
        flags |= F_INITIALISED
        # the sensor filter's lag undone (undo_sensor_lag), y at t_k from the two samples around it
        if regime == STANDSTILL:
            flags |= F_STANDSTILL
            out[O_ACC] = 0.0
            y_edge = 0.0
        else:
            out[O_ACC] = m[M_U_PREV] - x[2]
            y_edge = 0.5 * (u_before + m[M_U_PREV]) - x[2] if regime_prev == MOTION else 0.0
        out[O_POS], out[O_VEL] = undo_sensor_lag(x[0], x[1], y_edge, prm[P_LAG])
        out[O_BIAS] = x[2]
        out[O_POS_VAR] = with_scale_error(P[0, 0], out[O_POS], prm) + reading_instant_var(m[M_READING_DRIFT]) \
            + m[M_DISAGREE_VAR]
        out[O_VEL_VAR] = with_scale_error(P[1, 1], out[O_VEL], prm)
        out[O_BIAS_VAR] = P[2, 2]
    if regime == UNINITIALISED or m[M_BIAS_REQUESTED] > 0.0:
        flags |= F_BIAS_ESTIMATING
    if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2]) and math.isfinite(P[0, 0])
            and math.isfinite(P[1, 1]) and math.isfinite(P[2, 2])) or abs(x[1]) > DIVERGED_SPEED_MPS:
        flags |= F_FAULT
    out[O_INNOV] = upd.zaru_innovation
    out[O_NIS] = upd.zaru_innovation * upd.zaru_innovation / upd.zaru_var if upd.zaru_var > 0.0 else 0.0
    out[O_ZUPT_INNOV] = m[M_ZUPT_INNOV]
    out[O_ZUPT_NIS] = m[M_ZUPT_NIS]
    if m[M_UNTRUSTED] > 0.0:
        flags |= F_UNTRUSTED
    out[O_FLAGS] = flags
    out[O_TRANSITION] = upd.transition
    out[O_ZARU_Y] = upd.zaru_innovation
    out[O_ZARU_S] = upd.zaru_var
    out[O_ZUPT_Y] = upd.zupt_innovation
    out[O_ZUPT_S] = upd.zupt_var
    out[O_ZUPT_K0] = upd.gain_p
    out[O_ZUPT_K1] = upd.gain_v
    out[O_ZUPT_K2] = upd.gain_b
    out[O_ROLLBACK_FROM] = rollback_from


@jit_without_refcounts
def step(state, prm, t_s, z, z_valid, lost_before):
    """One sample in, the estimate at t_s out (written to `state.out`, layout O_*), in named
    phases: propagate → judge the standstill (a StandstillDecision) → roll back a gentle
    start → update → remember the sample → write the estimate."""
    x, P, m, ring_z, ring_ok, snap, gain, out = state
    count = int(m[M_COUNT])
    ok = z_valid and math.isfinite(z)
    flags, transition, regime_prev = propagate(x, P, m, prm, t_s, z, ok, lost_before, int(m[M_REGIME]))
    decision = judge_standstill(x, P, m, ring_z, ring_ok, prm, t_s, z, ok, regime_prev)
    flags |= decision.flags
    if decision.transition != T_NONE:
        transition = decision.transition
    rollback_from = -1
    if decision.decided and decision.regime == MOTION and regime_prev == STANDSTILL:
        rollback_from = roll_back_to_onset(x, P, m, snap, prm, t_s, z, lost_before, count)
        if rollback_from >= 0:
            transition = T_MOTION
            flags |= F_ROLLBACK
    upd = apply_updates(x, P, m, gain, prm, t_s, z, ok, decision, regime_prev, count)
    flags |= upd.flags
    if upd.transition != T_NONE:
        transition = upd.transition
    soft, soft_y, soft_s = soft_hinted_update(x, P, m, ring_z, ring_ok, gain, prm, z, ok, decision)
    if soft:
        flags |= F_HINT_SOFT
        upd = UpdateRecord(upd.zaru_innovation, upd.zaru_var, soft_y, soft_s, gain[0], gain[1],
                           gain[2], upd.flags, transition)
    else:
        upd = UpdateRecord(upd.zaru_innovation, upd.zaru_var, upd.zupt_innovation, upd.zupt_var, upd.gain_p,
                           upd.gain_v, upd.gain_b, upd.flags, transition)
    u_before = remember_sample(x, P, m, snap, z, ok, lost_before, count, decision.regime)
    write_estimate(x, P, m, out, prm, decision.regime, regime_prev, u_before, flags, upd, rollback_from)


def new_state(prm: np.ndarray) -> KernelState:
    """Fresh filter memory for these parameters (EstimatorSettings.kernel_params)."""
    w = int(prm[P_WINDOW])
    x = np.zeros(3)
    P = np.zeros((3, 3))
    P[2, 2] = prm[P_BIAS0_VAR]
    m = np.zeros(N_MISC)
    m[M_REGIME] = UNINITIALISED
    m[M_QUIET_T0] = math.nan
    m[M_LAST_REST_HINT_T] = -math.inf
    m[M_QUIET_FROM_V] = math.nan
    return KernelState(x, P, m, np.zeros(w), np.zeros(w), np.zeros((w, N_SNAP)), np.zeros(3), np.zeros(N_OUT))


def tare(state: KernelState) -> None:
    """Position := 0 here; it is then exact by definition (no variance, no correlation)."""
    state.x[0] = 0.0
    state.P[0, :] = 0.0
    state.P[:, 0] = 0.0
    state.misc[M_READING_DRIFT] = 0.0
    state.misc[M_DISAGREE_VAR] = 0.0


def request_bias_reestimate(state: KernelState, prm: np.ndarray) -> None:
    """Widen the bias variance back to its initial value: the next standstill re-measures
    it (and `F_BIAS_ESTIMATING` is set until a standstill begins)."""
    state.P[2, 2] = max(state.P[2, 2], prm[P_BIAS0_VAR])
    state.misc[M_BIAS_REQUESTED] = 1.0


@jit
def soft_update_bound(hint, w):
    """The most soft hinted velocity updates (soft_hinted_update) a run over `hint` can make — one per
    hinted sample from the MIN_WINDOW_SAMPLES-th to the w-th of its hinted run: room for
    their records, so that the smoother's forward pass need not run twice."""
    run = 0
    total = 0
    for k in range(hint.size):
        if hint_code(hint[k]) > 0.0:
            run += 1
            if MIN_WINDOW_SAMPLES <= run <= w:
                total += 1
        else:
            run = 0
    return total


@jit
def run_forward(prm, t_s, z, z_ok, lost, hint, state,
                pos, vel, acc, bias, pos_var, vel_var, bias_var, innov, nis, zupt_innov, flags,
                store, st_x, st_p, st_trans, st_zaru, zupt_index, zupt_data):
    """The step over whole arrays (hint: the machine's standstill hint per sample, NaN unknown).
    With store, keeps what the smoother needs:
    filtered x (N×3) and P (N×6: 00 01 02 11 12 22), the transition into each sample,
    ZARU (y, S) per sample, and the sparse velocity-update records (index; y, S, K0, K1, K2):
    the ZUPTs and the soft hinted updates (soft_hinted_update).
    After a rollback the records of the samples run again are rewritten (motion, no
    update), so the smoother sees the sequence the filter state now stands on.
    Returns the number of ZUPT records (more than zupt_index holds: run again with room)."""
    x, P, m, out, snap = state.x, state.P, state.misc, state.out, state.snap
    n_zupt = 0
    for k in range(t_s.size):
        m[M_HINT] = hint_code(hint[k])
        step(state, prm, t_s[k], z[k], z_ok[k], lost[k])
        pos[k] = out[O_POS]
        vel[k] = out[O_VEL]
        acc[k] = out[O_ACC]
        bias[k] = out[O_BIAS]
        pos_var[k] = out[O_POS_VAR]
        vel_var[k] = out[O_VEL_VAR]
        bias_var[k] = out[O_BIAS_VAR]
        innov[k] = out[O_INNOV]
        nis[k] = out[O_NIS]
        zupt_innov[k] = out[O_ZUPT_INNOV]
        flags[k] = int(out[O_FLAGS])
        if store:
            s = int(out[O_ROLLBACK_FROM])
            if s >= 0:
                w = int(prm[P_WINDOW])
                for j in range(s + 1, k):
                    row = j % w
                    for c in range(3):
                        st_x[j, c] = snap[row, c]
                    for c in range(6):
                        st_p[j, c] = snap[row, 3 + c]
                    st_trans[j] = T_MOTION
                    st_zaru[j, 0] = 0.0
                    st_zaru[j, 1] = 0.0
                    flags[j] = (flags[j] & ~F_STANDSTILL) | F_ROLLBACK
            st_x[k, 0] = x[0]
            st_x[k, 1] = x[1]
            st_x[k, 2] = x[2]
            pack_cov(P, st_p[k], 0)
            st_trans[k] = int(out[O_TRANSITION])
            st_zaru[k, 0] = out[O_ZARU_Y]
            st_zaru[k, 1] = out[O_ZARU_S]
            if out[O_ZUPT_S] > 0.0:
                if n_zupt >= zupt_index.size:  # caller re-runs with room for all
                    n_zupt += 1
                    continue
                zupt_index[n_zupt] = k
                zupt_data[n_zupt, 0] = out[O_ZUPT_Y]
                zupt_data[n_zupt, 1] = out[O_ZUPT_S]
                zupt_data[n_zupt, 2] = out[O_ZUPT_K0]
                zupt_data[n_zupt, 3] = out[O_ZUPT_K1]
                zupt_data[n_zupt, 4] = out[O_ZUPT_K2]
                n_zupt += 1
    return n_zupt
