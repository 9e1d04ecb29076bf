"""Phase 3 of the estimator kernel's step: the rollback to a gentle start's onset, the
updates a standstill brings (reference point, ZUPT, ZARU) and the soft hinted update;
each sample's updates as an UpdateRecord (what the smoother replays)."""
from __future__ import annotations

import math
from typing import NamedTuple

from gateway.core.jit import jit, jit_inline
from gateway.core.kernel_layout import (
    F_ENTRY,
    F_HINT_IN_MOTION,
    F_HINT_REST,
    M_BIAS_REQUESTED,
    M_DISAGREE_VAR,
    M_HINT_RUN,
    M_LAST_STILL_T,
    M_LAST_STOP_POS,
    M_MOVES_SQ,
    M_PEAK_SPEED,
    M_PERIOD,
    M_RING_FILL,
    M_RING_POS,
    M_STEP_OPEN,
    M_STILL_START,
    M_UNTRUSTED,
    M_ZUPT_INNOV,
    M_ZUPT_NIS,
    MOTION,
    P_BIAS0_VAR,
    P_LAG,
    P_MEAN_SIGMAS,
    P_MISSING_VAR,
    P_QB,
    P_QV,
    P_R,
    P_R_ZUPT,
    P_SCALE_VAR,
    P_SPEED_FLOOR,
    P_STEP_MAX,
    P_VAR_MAX,
    P_WINDOW,
    P_ZUPT_CHI2,
    STANDSTILL,
    T_NONE,
    T_RESET,
    UNINITIALISED,
    hint_code,
    pack_state,
    unpack_cov,
)
from gateway.core.kernel_output import disagreement_var, zupt_beyond_chance
from gateway.core.kernel_propagate import drift_at, propagate_motion, within_period_position_var
from gateway.core.standstill import (
    MIN_WINDOW_SAMPLES,
    hinted_rest_fits,
    mean_velocity_offset,
    true_velocity_swing,
    velocity_changes_beyond_noise,
    velocity_consistent_with_rest,
)


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


@jit_inline
def roll_back_to_onset(x, P, m, snap, prm, t_s, z, ok, lost_before, count):
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
    u2 = snap[j, 13]
    for i in range(s + 1, count + 1):
        ji = i % w
        if i < count:
            t_i = snap[ji, 9]
            lost_i = int(snap[ji, 12])
            z_i, ok_i = snap[ji, 10], snap[ji, 11] > 0.0
        else:
            t_i = t_s
            lost_i = lost_before
            z_i, ok_i = z, ok
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
            if missing_dt == 0.0 and ok_i:
                P[0, 0] += within_period_position_var(u2, u, z_i, dt_i)
            t_before = t_i
        if i < count:
            pack_state(x, P, snap[ji], 0)
            if snap[ji, 11] > 0.0:
                u2 = u if not u_stale else snap[ji, 10]
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
            if d.hint_disagrees or d.hinted_in_motion or zupt_beyond_chance(zupt_y, zupt_s, prm[P_SCALE_VAR],
                                                                            prm[P_ZUPT_CHI2]):
                # the two answers — the stop and the integrated motion — differ by the
                # position this update moved: the reported σ covers both (disagreement_var;
                # a hinted stop that disagrees is also flagged, by hint_gate; one whose
                # window still changes the velocity may have come before the axis stood)
                m[M_DISAGREE_VAR] += disagreement_var(gain[0], zupt_y)
            if d.hinted_in_motion:
                flags |= F_HINT_IN_MOTION
            flags |= F_ENTRY
            # a move closed: its displacement for the sensitivity's share (scale_position_var)
            move = x[0] - m[M_LAST_STOP_POS]
            m[M_MOVES_SQ] += move * move
            m[M_LAST_STOP_POS] = x[0]
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


class SoftUpdate(NamedTuple):
    """What soft_hinted_update did at one sample."""

    applied: bool
    innovation: float  # the velocity innovation (m/s)
    innovation_var: float  # its variance S
    in_motion: bool  # the hinted samples hold part of a motion: σ covers the update and its absence
    refused: bool  # the accelerometer contradicts the machine beyond chance: no update, flags 512 and 256


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
    - not when the hinted samples show an acceleration of the machine (hinted_rest_fits:
      mean off the bias beyond an offset step and their spread, or a swing beyond the
      floor);
    - not when the accelerometer contradicts it: its velocity innovation beyond χ²₁ at
      the detector's false-alarm rate (velocity_consistent_with_rest, its variance the
      filter's σ_v², the sensitivity's share and the update's own noise) — a cruise the
      filter knows, slow or fast, hinted at rest. The machine and the integrated
      accelerometer then disagree beyond chance: no update, flag 512 and the position
      untrusted (256) until a stop both agree on, as for a hinted stop that disagrees;
    - the k-th look at the same rest shares its error with the others (one mount's
      ringing, the samples correlated): it counts with k·σ², so the looks weigh
      together as ~ln k + 0.6 measurements of that σ, not as k independent ones;
    - hinted samples whose velocity range is beyond their noise
      (velocity_changes_beyond_noise) hold part of a motion: the update is one answer of
      two, and σ covers both (in_motion; estimator_kernel.step).
    Returns a SoftUpdate; the gain is in `gain`."""
    w = int(prm[P_WINDOW])
    floor = prm[P_SPEED_FLOOR]
    hint_run = int(m[M_HINT_RUN])
    if not (d.regime == MOTION and d.hint > 0.0 and MIN_WINDOW_SAMPLES <= hint_run <= w):
        return SoftUpdate(False, 0.0, 0.0, False, False)
    n_hinted = min(hint_run, int(m[M_RING_FILL]))
    oldest = (int(m[M_RING_POS]) - n_hinted + w) % w
    if not hinted_rest_fits(ring_z, ring_ok, oldest, n_hinted, x[2], P[2, 2], prm[P_R], prm[P_STEP_MAX],
                            prm[P_MEAN_SIGMAS], floor, m[M_PERIOD]):
        return SoftUpdate(False, 0.0, 0.0, False, False)
    looks = hint_run - MIN_WINDOW_SAMPLES + 1
    offset, half_range = mean_velocity_offset(ring_z, ring_ok, oldest, n_hinted, x[2], m[M_PERIOD])
    noise_var = looks * max(half_range * half_range, prm[P_R_ZUPT])
    innovation = offset - (x[1] + prm[P_LAG] * (z - x[2]) if ok else x[1])
    if not velocity_consistent_with_rest(innovation, P[1, 1], prm[P_SCALE_VAR], noise_var, prm[P_ZUPT_CHI2]):
        m[M_UNTRUSTED] = 1.0
        return SoftUpdate(False, 0.0, 0.0, False, True)
    y, s = rest_velocity_update(x, P, z, ok, prm[P_LAG], offset, noise_var, gain)
    swing = true_velocity_swing(ring_z, ring_ok, oldest, n_hinted, x[2], m[M_PERIOD], prm[P_LAG])
    in_motion = velocity_changes_beyond_noise(swing, n_hinted, prm[P_R], m[M_PERIOD], prm[P_MEAN_SIGMAS])
    return SoftUpdate(True, y, s, in_motion, False)


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
