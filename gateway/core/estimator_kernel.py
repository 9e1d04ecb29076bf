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

from gateway.core.jit import jit, jit_without_refcounts
from gateway.core.kernel_layout import (
    DIVERGED_SPEED_MPS,
    F_BIAS_ESTIMATING,
    F_ENTRY,
    F_FAULT,
    F_GAP,
    F_HINT_CONFLICT,
    F_HINT_IN_MOTION,
    F_HINT_REST,
    F_HINT_SOFT,
    F_INITIALISED,
    F_INPUT_INVALID,
    F_OFFSET_STEP,
    F_ROLLBACK,
    F_STANDSTILL,
    F_TIME_ERROR,
    F_UNDECIDED,
    F_UNTRUSTED,
    M_BIAS_REQUESTED,
    M_COUNT,
    M_DISAGREE_VAR,
    M_HAVE_PREV,
    M_HAVE_U,
    M_HINT,
    M_HINT_RUN,
    M_LAST_REST_HINT_T,
    M_LAST_STILL_T,
    M_LAST_STOP_POS,
    M_MOVES_SQ,
    M_PEAK_SPEED,
    M_PERIOD,
    M_PREV_INVALID,
    M_QUIET_FROM_T,
    M_QUIET_FROM_V,
    M_QUIET_T0,
    M_READING_DRIFT,
    M_REGIME,
    M_RING_FILL,
    M_RING_POS,
    M_STEP_OPEN,
    M_STILL_START,
    M_T_PREV,
    M_U_PREV,
    M_U_PREV2,
    M_UNTRUSTED,
    M_VEL_UNKNOWN,
    M_ZUPT_INNOV,
    M_ZUPT_NIS,
    MOTION,
    N_MISC,
    N_OUT,
    N_PARAMS,
    N_SNAP,
    O_ACC,
    O_BIAS,
    O_BIAS_VAR,
    O_FLAGS,
    O_INNOV,
    O_NIS,
    O_POS,
    O_POS_VAR,
    O_ROLLBACK_FROM,
    O_TRANSITION,
    O_VEL,
    O_VEL_VAR,
    O_ZARU_S,
    O_ZARU_Y,
    O_ZUPT_INNOV,
    O_ZUPT_K0,
    O_ZUPT_K1,
    O_ZUPT_K2,
    O_ZUPT_NIS,
    O_ZUPT_S,
    O_ZUPT_Y,
    P_BIAS0_VAR,
    P_DRIFT_C1,
    P_DRIFT_T,
    P_DRIFT_T0,
    P_HINT_LATENCY,
    P_LAG,
    P_MEAN_SIGMAS,
    P_MISSING_VAR,
    P_QB,
    P_QUIET_STOP_S,
    P_QV,
    P_R,
    P_R_ZUPT,
    P_READING_INSTANT,
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
    T_MOTION,
    T_NONE,
    T_RESET,
    T_STANDSTILL,
    UNINITIALISED,
    KernelState,
    hint_code,
    mark_velocity_unknown,
    new_state,
    pack_cov,
    pack_state,
    request_bias_reestimate,
    set_hint,
    tare,
    unpack_cov,
)
from gateway.core.kernel_output import (
    add_reading_instant_error,
    add_scale_error,
    add_scale_position_error,
    disagreement_var,
    exact_update_gain_pos,
    lag_undone_position_var,
    reading_instant_var,
    remember_sample,
    scale_position_var,
    undo_sensor_lag,
    with_scale_error,
    write_estimate,
    zupt_beyond_chance,
)
from gateway.core.kernel_propagate import (
    drift_at,
    propagate,
    propagate_motion,
    propagate_standstill,
    within_period_position_var,
)
from gateway.core.kernel_standstill_judge import (
    StandstillDecision,
    hint_as_taken,
    hint_gate,
    hinted_entry_in_motion,
    judge_standstill,
    offset_step_hypotheses,
    open_offset_step,
    start_moving_after_restart,
    undecidable_quiet,
    window_of,
    window_tests,
)
from gateway.core.kernel_update import (
    SoftUpdate,
    UpdateRecord,
    apply_updates,
    rest_velocity_update,
    roll_back_to_onset,
    scalar_update,
    soft_hinted_update,
    soft_update_bound,
)

# the one public entry: every caller imports the kernel from here (layout, records, phases)
__all__ = [
    'DIVERGED_SPEED_MPS', 'F_BIAS_ESTIMATING', 'F_ENTRY', 'F_FAULT', 'F_GAP', 'F_HINT_CONFLICT', 'F_HINT_REST',
    'F_HINT_IN_MOTION',
    'F_HINT_SOFT', 'F_INITIALISED', 'F_INPUT_INVALID', 'F_OFFSET_STEP', 'F_ROLLBACK', 'F_STANDSTILL',
    'F_TIME_ERROR', 'F_UNDECIDED', 'F_UNTRUSTED', 'KernelState', 'MOTION', 'M_BIAS_REQUESTED', 'M_COUNT',
    'M_DISAGREE_VAR', 'M_HAVE_PREV', 'M_HAVE_U', 'M_HINT', 'M_HINT_RUN', 'M_LAST_REST_HINT_T', 'M_LAST_STILL_T',
    'M_PEAK_SPEED', 'M_PERIOD', 'M_PREV_INVALID', 'M_QUIET_FROM_T', 'M_QUIET_FROM_V', 'M_QUIET_T0',
    'M_READING_DRIFT', 'M_REGIME', 'M_RING_FILL', 'M_RING_POS', 'M_STEP_OPEN', 'M_STILL_START', 'M_T_PREV',
    'M_UNTRUSTED', 'M_U_PREV', 'M_U_PREV2', 'M_VEL_UNKNOWN', 'M_ZUPT_INNOV', 'M_ZUPT_NIS', 'N_MISC', 'N_OUT',
    'N_PARAMS',
    'N_SNAP', 'O_ACC', 'O_BIAS', 'O_BIAS_VAR', 'O_FLAGS', 'O_INNOV', 'O_NIS', 'O_POS', 'O_POS_VAR',
    'O_ROLLBACK_FROM', 'O_TRANSITION', 'O_VEL', 'O_VEL_VAR', 'O_ZARU_S', 'O_ZARU_Y', 'O_ZUPT_INNOV', 'O_ZUPT_K0',
    'O_ZUPT_K1', 'O_ZUPT_K2', 'O_ZUPT_NIS', 'O_ZUPT_S', 'O_ZUPT_Y', 'P_BIAS0_VAR', 'P_DRIFT_C1', 'P_DRIFT_T',
    'P_DRIFT_T0', 'P_HINT_LATENCY', 'P_LAG', 'P_MEAN_SIGMAS', 'P_MISSING_VAR', 'P_QB', 'P_QUIET_STOP_S', 'P_QV',
    'P_R', 'P_READING_INSTANT', 'P_RESTART_VEL_VAR', 'P_R_ZUPT', 'P_SCALE_VAR', 'P_SPEED_FLOOR', 'P_STEP_MAX',
    'P_VAR_MAX', 'P_VEL_SIGMAS', 'P_VIBRATION', 'P_WINDOW', 'P_ZUPT_CHI2', 'STANDSTILL', 'SoftUpdate',
    'StandstillDecision',
    'T_MOTION', 'T_NONE', 'T_RESET', 'T_STANDSTILL', 'UNINITIALISED', 'UpdateRecord', 'add_reading_instant_error',
    'add_scale_error', 'apply_updates', 'disagreement_var', 'drift_at', 'exact_update_gain_pos', 'hint_as_taken',
    'hint_code', 'hint_gate',
    'hinted_entry_in_motion',
    'judge_standstill', 'lag_undone_position_var', 'mark_velocity_unknown', 'new_state', 'offset_step_hypotheses',
    'open_offset_step',
    'pack_cov', 'pack_state', 'propagate', 'propagate_motion', 'propagate_standstill', 'reading_instant_var',
    'remember_sample', 'request_bias_reestimate', 'rest_velocity_update', 'roll_back_to_onset', 'scalar_update',
    'set_hint', 'soft_hinted_update', 'soft_update_bound', 'start_moving_after_restart', 'tare',
    'undecidable_quiet', 'undo_sensor_lag', 'unpack_cov', 'window_of', 'window_tests', 'with_scale_error',
    'within_period_position_var',
    'write_estimate', 'run_forward', 'step', 'zupt_beyond_chance', 'add_scale_position_error', 'scale_position_var',
    'M_LAST_STOP_POS', 'M_MOVES_SQ',
]


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
        rollback_from = roll_back_to_onset(x, P, m, snap, prm, t_s, z, ok, lost_before, count)
        if rollback_from >= 0:
            transition = T_MOTION
            flags |= F_ROLLBACK
    upd = apply_updates(x, P, m, gain, prm, t_s, z, ok, decision, regime_prev, count)
    flags |= upd.flags
    if upd.transition != T_NONE:
        transition = upd.transition
    soft = soft_hinted_update(x, P, m, ring_z, ring_ok, gain, prm, z, ok, decision)
    if soft.refused:
        flags |= F_HINT_CONFLICT
    if soft.applied:
        flags |= F_HINT_SOFT
        if soft.in_motion:
            flags |= F_HINT_IN_MOTION
        if soft.in_motion or zupt_beyond_chance(soft.innovation, soft.innovation_var, prm[P_SCALE_VAR],
                                                prm[P_ZUPT_CHI2]):
            # the machine's "at rest" against a velocity beyond chance, or on samples that
            # hold part of a motion: σ covers both answers — on samples in motion, the word
            # made exact (the axis stopped among them: v = 0 now) and no update
            m[M_DISAGREE_VAR] += disagreement_var(
                exact_update_gain_pos(gain[0], gain[1]) if soft.in_motion else gain[0], soft.innovation)
        upd = UpdateRecord(upd.zaru_innovation, upd.zaru_var, soft.innovation, soft.innovation_var, gain[0],
                           gain[1], gain[2], upd.flags, transition)
    else:
        upd = UpdateRecord(upd.zaru_innovation, upd.zaru_var, upd.zupt_innovation, upd.zupt_var, upd.gain_p,
                           upd.gain_v, upd.gain_b, upd.flags, transition)
    u_before = remember_sample(x, P, m, snap, z, ok, lost_before, count, decision.regime)
    write_estimate(x, P, m, out, prm, decision.regime, regime_prev, u_before, flags, upd, rollback_from)


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
