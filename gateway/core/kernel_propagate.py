"""Phase 1 of the estimator kernel's step: the state from the previous sample's time to this
one's, driven by the previous sample's acceleration (the model: estimator_kernel)."""
from __future__ import annotations

import math

from gateway.core.jit import jit, jit_inline
from gateway.core.kernel_layout import (
    F_GAP,
    F_TIME_ERROR,
    M_HAVE_PREV,
    M_HAVE_U,
    M_PERIOD,
    M_PREV_INVALID,
    M_READING_DRIFT,
    M_T_PREV,
    M_U_PREV,
    M_U_PREV2,
    MOTION,
    P_DRIFT_C1,
    P_DRIFT_T,
    P_DRIFT_T0,
    P_MISSING_VAR,
    P_QB,
    P_QV,
    P_R,
    P_READING_INSTANT,
    STANDSTILL,
    T_MOTION,
    T_NONE,
    T_STANDSTILL,
)


@jit
def drift_at(t_s, prm):
    return prm[P_DRIFT_C1] * -math.expm1(-(t_s + prm[P_DRIFT_T0]) / prm[P_DRIFT_T])


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
def within_period_position_var(z_before, z_held, z_after, dt):
    """The position's variance from not knowing how the acceleration moved inside the
    held period. The duty cycle gives the period's mean, which integrates the velocity
    exactly but not the position: an acceleration stepping at an instant u·dt inside the
    period moves the position by −A·dt²/2·u(1−u) against the held mean, up to A·dt²/8. A
    monotone change inside the period stays within the range of its own mean and its
    neighbours', which bounds A; the error is taken as uniform within ±range·dt²/8.
    Negligible at the noise's scale (a 0.1 m/s² range at 2 ms: 5e-8 m); at a move's first
    samples it is the position's uncertainty (docs/estimation.md, "Model")."""
    spread = max(z_before, z_held, z_after) - min(z_before, z_held, z_after)
    bound = spread * dt * dt / 8.0
    return bound * bound / 3.0


@jit
def propagate_standstill(x, P, dt, ddrift, qb):
    """At rest: v ≡ 0, position held, only the bias moves (drift + random walk)."""
    x[1] = 0.0
    x[2] += ddrift
    for i in range(3):
        P[1, i] = 0.0
        P[i, 1] = 0.0
    P[2, 2] += qb * dt


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
            if missing_dt == 0.0 and ok:
                P[0, 0] += within_period_position_var(m[M_U_PREV2], u, z, dt)
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
