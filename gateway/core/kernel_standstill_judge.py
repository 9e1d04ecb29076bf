"""Phase 2 of the estimator kernel's step: the standstill judgement on the window ending at
this sample. It returns a StandstillDecision — what was tested, with which statistic,
what was decided — and the update phase reads only that record: this module is the seam
where the detector can be replaced. The tests themselves and their principles are in
gateway/core/standstill.py."""
from __future__ import annotations

import math
from typing import NamedTuple

from gateway.core.jit import jit, jit_inline
from gateway.core.kernel_layout import (
    F_HINT_CONFLICT,
    F_HINT_REST,
    F_INPUT_INVALID,
    F_OFFSET_STEP,
    F_UNDECIDED,
    M_HINT,
    M_HINT_RUN,
    M_LAST_REST_HINT_T,
    M_LAST_STILL_T,
    M_PEAK_SPEED,
    M_PERIOD,
    M_QUIET_FROM_T,
    M_QUIET_FROM_V,
    M_QUIET_T0,
    M_RING_FILL,
    M_RING_POS,
    M_STEP_OPEN,
    M_UNTRUSTED,
    M_VEL_UNKNOWN,
    MOTION,
    P_HINT_LATENCY,
    P_LAG,
    P_MEAN_SIGMAS,
    P_QUIET_STOP_S,
    P_R,
    P_R_ZUPT,
    P_RESTART_VEL_VAR,
    P_SCALE_VAR,
    P_SPEED_FLOOR,
    P_STEP_MAX,
    P_VAR_MAX,
    P_VEL_SIGMAS,
    P_VIBRATION,
    P_WINDOW,
    P_ZUPT_CHI2,
    STANDSTILL,
    T_NONE,
    T_RESET,
    UNINITIALISED,
)
from gateway.core.standstill import (
    hint_gate_open,
    standstill_tests,
    stopping_within_a_window,
    true_velocity_swing,
    velocity_changes_beyond_noise,
    velocity_consistent_with_rest,
    velocity_decidable,
    velocity_swing,
    window_statistics,
)


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
    # a stop entered on the machine's word whose window still changes the velocity beyond the noise
    # (hinted_entry_in_motion): σ will cover the position with and without its ZUPT
    hinted_in_motion: bool


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
def hinted_entry_in_motion(x, m, ring_z, ring_ok, prm, fill):
    """A stop entered on the machine's "at rest" whose window's acceleration (the bias
    removed) still swings the velocity beyond the noise (velocity_changes_beyond_noise).
    The gate lets such a window through when its mean sits at the bias within its spread
    (a ringing mount), and a window holding the last of a deceleration can look the same
    (the deceleration widens the spread it is judged against). When the axis stood still
    is then not known from the window: the word may lead the stop by more than a window
    (a controller's "in position" before the servo settles), and the ZUPT's position
    correction, Cov(p, v)/Var(v) times a velocity that may still be real, is one answer
    of two — the reported σ covers both (kernel_update.apply_updates)."""
    w = int(prm[P_WINDOW])
    oldest = int(m[M_RING_POS]) % w if fill >= w else 0
    swing = true_velocity_swing(ring_z, ring_ok, oldest, fill, x[2], m[M_PERIOD], prm[P_LAG])
    return velocity_changes_beyond_noise(swing, fill, prm[P_R], m[M_PERIOD], prm[P_MEAN_SIGMAS])


@jit_inline
def undecidable_quiet(x, m, prm, t_s, regime_prev, hint, mean, vibrating, var_ok, mean_ok, decidable, still):
    """What a quiet stretch in motion that no test accepts as a stop makes of the position.
    Returns (still, flags).

    - the velocity test cannot decide (the filter lost its velocity: a gap, an outage, a
      long time since the latest stop): a stop only once the stretch has lasted longer than
      any cruise within the travel (P_QUIET_STOP_S: travel / speed floor); the position untrusted;
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
    hinted_in_motion = regime == STANDSTILL and regime_prev == MOTION and hint > 0.0 and hinted_entry_in_motion(
        x, m, ring_z, ring_ok, prm, fill)
    return StandstillDecision(decided, regime, n_valid, mean, var_raw, prm[P_VAR_MAX], var_ok, mean_ok, vel_ok,
                              decidable, trusted_entry, disagrees, zaru_ok, hint, flags, transition,
                              hinted_in_motion)
