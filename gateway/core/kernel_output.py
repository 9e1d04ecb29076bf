"""Phase 4 of the estimator kernel's step: the sample remembered (snapshot ring, held input)
and the estimate written to the output (O_*): the sensor's lag undone, the reported
variances with what the model cannot see (sensitivity, reading instant, a hint's
disagreement), the health flags."""
from __future__ import annotations

import math

from gateway.core.jit import jit, jit_inline
from gateway.core.kernel_layout import (
    DIVERGED_SPEED_MPS,
    F_BIAS_ESTIMATING,
    F_ENTRY,
    F_FAULT,
    F_INITIALISED,
    F_STANDSTILL,
    F_UNTRUSTED,
    M_BIAS_REQUESTED,
    M_COUNT,
    M_DISAGREE_VAR,
    M_HAVE_U,
    M_LAST_STOP_POS,
    M_MOVES_SQ,
    M_PREV_INVALID,
    M_READING_DRIFT,
    M_REGIME,
    M_T_PREV,
    M_U_PREV,
    M_U_PREV2,
    M_UNTRUSTED,
    M_ZUPT_INNOV,
    M_ZUPT_NIS,
    MOTION,
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
    P_LAG,
    P_READING_INSTANT,
    P_SCALE_VAR,
    STANDSTILL,
    UNINITIALISED,
    pack_state,
)


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
def lag_undone_position_var(P, lag):
    """The variance of the position undo_sensor_lag reports, p + τ·v: Var(p) + 2τ·Cov(p, v)
    + τ²·Var(v). Var(p) alone leaves out the velocity's share, the whole of the reported
    position's uncertainty at a move's first samples (where Var(p) is still ~0)."""
    return P[0, 0] + 2.0 * lag * P[0, 1] + lag * lag * P[1, 1]


@jit
def disagreement_var(gain_pos, innovation):
    """A stop whose velocity innovation is beyond chance (zupt_beyond_chance: the machine's
    hint against the integrated velocity, or a quiet window after a move whose integrated
    velocity the model's noise cannot explain): the position with the stop and without it
    differ by the update's position correction K_p·y; the reported variance adds its square,
    so that σ covers both answers. gain_pos is the exact update's (exact_update_gain_pos)."""
    d = gain_pos * innovation
    return d * d


@jit
def exact_update_gain_pos(gain_pos, gain_vel):
    """The position an exact velocity update (noise 0) moves per unit of innovation,
    P_pv/P_vv, from a made update's gains K_p = P_pv/S and K_v = P_vv/S. A stop's ZUPT is
    exact to 10 µm/s (K_v ≈ 1: the same); a soft hinted update is not — its noise is the
    hinted samples' velocity range, a ringing's partial period —, so it moves the position
    by a fraction K_v of what an exact one would. On samples that hold part of a motion
    (F_HINT_IN_MOTION) that range is the deceleration's, not a ringing's: if the word is
    right the axis stopped among them and its velocity is 0 now, exactly; if it came early,
    no update is right. σ covers those two answers."""
    return gain_pos / gain_vel if gain_vel > 0.0 else gain_pos


@jit
def zupt_beyond_chance(innovation, innovation_var, scale_var, chi2_max):
    """A stop's velocity innovation y (variance S = σ_v² + R, before the update) is no chance:
    y² > χ²₁(1 − p)·(S + s²·y²) — the test of standstill.velocity_consistent_with_rest at the
    detector's false-alarm rate p. Then the velocity error has a source the model does not
    contain (a tilt putting gravity on the axis, an offset that moved, a gain error on the
    pulses), and where in the move it arose the data do not say: the position correction the
    ZUPT makes through Cov(p, v)/Var(v) — the white-noise shape of the error — is one answer
    among those from "at the start" to "at the end", which differ by up to that correction."""
    return innovation * innovation > chi2_max * (innovation_var + scale_var * innovation * innovation)


@jit
def with_scale_error(var, value, prm):
    """A variance from the filter with the sensitivity's share added: a reading (1 + s)·a
    makes the velocity off by s·v and the position by s·p (p since the tare), a systematic
    error the filter's model does not contain."""
    return var + prm[P_SCALE_VAR] * value * value


@jit
def scale_position_var(pos, moves_sq, last_stop_pos, scale_var):
    """The sensitivity's share of the position's variance: a reading (1 + s)·a puts each move
    s·Δp off, and a ZUPT cannot see it (a symmetric pulse's gain error leaves no velocity at
    the stop). If s is one constant, the errors add to s·p (p since the tare); if a pulse's
    gain is not the same on every move (a sensor's nonlinearity and cross-axis terms depend
    on the acceleration's size and direction: the robot's fast vertical moves read 4.4 %
    and 4.8 % short, then 2.5 % long), they add as √Σ(s·Δp)². The data sheet's tolerance
    bounds s, not how it varies between moves: the variance covers both, σ_s²·max(p², ΣΔp²)
    — moves closed by a stop (moves_sq) and the current one since the latest stop."""
    d = pos - last_stop_pos
    return scale_var * max(pos * pos, moves_sq + d * d)


@jit
def add_scale_position_error(var, pos, flags, prm):
    """scale_position_var over a track, in place (no new array: the smoothed estimate's memory
    budget), its moves cut at the stops the forward pass entered (F_ENTRY)."""
    moves_sq = 0.0
    last_stop_pos = 0.0
    for k in range(var.size):
        if flags[k] & F_ENTRY:
            d = pos[k] - last_stop_pos
            moves_sq += d * d
            last_stop_pos = pos[k]
        var[k] += scale_position_var(pos[k], moves_sq, last_stop_pos, prm[P_SCALE_VAR])


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
        m[M_U_PREV2] = m[M_U_PREV] if m[M_HAVE_U] > 0.0 and m[M_PREV_INVALID] == 0.0 else z
        m[M_U_PREV] = z
        m[M_PREV_INVALID] = 0.0
        m[M_HAVE_U] = 1.0
    else:
        m[M_PREV_INVALID] = 1.0
    snap[j, 13] = m[M_U_PREV2]  # a rollback's replay starts its input range from here
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
        out[O_POS_VAR] = lag_undone_position_var(P, prm[P_LAG]) \
            + scale_position_var(out[O_POS], m[M_MOVES_SQ], m[M_LAST_STOP_POS], prm[P_SCALE_VAR]) \
            + reading_instant_var(m[M_READING_DRIFT]) \
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
