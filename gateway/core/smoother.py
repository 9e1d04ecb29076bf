"""Backward pass for recordings: the realtime filter's model, smoothed over the whole record.

The modified Bryson–Frazier form of the Rauch–Tung–Striebel smoother (Bierman 1977):
it runs backward on adjoint variables λ, Λ and needs no inverse of a predicted
covariance — which matters here, because at standstill the velocity is exactly zero
(Φs has a zero row, P is singular) and right after the reference point the position is
exact. Per sample k, going backward (λ̂, Λ̂ start at 0 after the last sample):

    x_s = x_k − P_k·λ̂,   P_s = P_k − P_k·Λ̂·P_k                     (smoothed)
    for each scalar update at k, last applied first (H = e_i, y, S, K):
        λ̃ = (I − K·H)ᵀ·λ̂ − Hᵀ·y/S,   Λ̃ = (I − K·H)ᵀ·Λ̂·(I − K·H) + Hᵀ·H/S
    λ̂ ← Φ_kᵀ·λ̃,  Λ̂ ← Φ_kᵀ·Λ̃·Φ_k   (Φ_k: the transition into sample k)

The smoothed position over a standstill is constant (Φs holds it), and the position in
a motion is corrected by the velocity error found at the next stop and by the bias
measured at the stops on both sides.
"""
from __future__ import annotations

import numpy as np

from gateway.core.estimator_kernel import T_MOTION, T_RESET, T_STANDSTILL, unpack_cov
from gateway.core.jit import jit


@jit
def _undo_update(lam, L, i, K0, K1, K2, y, S):
    """λ̃ = λ − e_i (K·λ + y/S);  Λ̃ = (I − e_i Kᵀ) Λ (I − K e_iᵀ) + e_i e_iᵀ / S."""
    kl = K0 * lam[0] + K1 * lam[1] + K2 * lam[2]
    lam[i] -= kl + y / S
    # r = Λ K ; row i −= rᵀ ; then column i −= (new Λ) K
    r0 = L[0, 0] * K0 + L[0, 1] * K1 + L[0, 2] * K2
    r1 = L[1, 0] * K0 + L[1, 1] * K1 + L[1, 2] * K2
    r2 = L[2, 0] * K0 + L[2, 1] * K1 + L[2, 2] * K2
    L[i, 0] -= r0
    L[i, 1] -= r1
    L[i, 2] -= r2
    c0 = L[0, 0] * K0 + L[0, 1] * K1 + L[0, 2] * K2
    c1 = L[1, 0] * K0 + L[1, 1] * K1 + L[1, 2] * K2
    c2 = L[2, 0] * K0 + L[2, 1] * K1 + L[2, 2] * K2
    L[0, i] -= c0
    L[1, i] -= c1
    L[2, i] -= c2
    L[i, i] += 1.0 / S
    # exact symmetry (the algebra is symmetric; rounding is not)
    for a in range(3):
        for b in range(a + 1, 3):
            v = 0.5 * (L[a, b] + L[b, a])
            L[a, b] = v
            L[b, a] = v


@jit
def _through_motion(lam, L, dt):
    """λ ← Φᵀλ, Λ ← ΦᵀΛΦ for Φ = [[1, dt, −dt²/2], [0, 1, −dt], [0, 0, 1]]."""
    h = 0.5 * dt * dt
    l0 = lam[0]
    l1 = lam[1]
    l2 = lam[2]
    lam[0] = l0
    lam[1] = dt * l0 + l1
    lam[2] = -h * l0 - dt * l1 + l2
    # B = Φᵀ Λ (rows), then C = B Φ (columns)
    for j in range(3):
        b0 = L[0, j]
        b1 = dt * L[0, j] + L[1, j]
        b2 = -h * L[0, j] - dt * L[1, j] + L[2, j]
        L[0, j] = b0
        L[1, j] = b1
        L[2, j] = b2
    for i in range(3):
        c0 = L[i, 0]
        c1 = dt * L[i, 0] + L[i, 1]
        c2 = -h * L[i, 0] - dt * L[i, 1] + L[i, 2]
        L[i, 0] = c0
        L[i, 1] = c1
        L[i, 2] = c2


@jit
def run_backward(t_s, st_trans, st_x, st_p, st_zaru, r_zaru, zupt_index, zupt_data, n_zupt,
                 out_pos_var, out_vel_var, out_bias_var):
    """Smooth in place: st_x becomes the smoothed state; the smoothed variances go to out_*."""
    lam = np.zeros(3)
    L = np.zeros((3, 3))
    P = np.zeros((3, 3))
    j = n_zupt - 1
    for k in range(t_s.size - 1, -1, -1):
        unpack_cov(st_p[k], 0, P)
        # smoothed state and variances
        for a in range(3):
            corr = P[a, 0] * lam[0] + P[a, 1] * lam[1] + P[a, 2] * lam[2]
            st_x[k, a] -= corr
        for a in range(3):
            # (P Λ P)_aa
            q = 0.0
            for b in range(3):
                pb = P[a, 0] * L[0, b] + P[a, 1] * L[1, b] + P[a, 2] * L[2, b]
                q += pb * P[b, a]
            v = P[a, a] - q
            if v < 0.0:
                v = 0.0
            if a == 0:
                out_pos_var[k] = v
            elif a == 1:
                out_vel_var[k] = v
            else:
                out_bias_var[k] = v
        # undo the updates at k, the last applied (ZARU) first; its gain is P_k e_2 / R
        if st_zaru[k, 1] > 0.0:
            _undo_update(lam, L, 2, P[0, 2] / r_zaru, P[1, 2] / r_zaru, P[2, 2] / r_zaru,
                         st_zaru[k, 0], st_zaru[k, 1])
        if j >= 0 and zupt_index[j] == k:
            _undo_update(lam, L, 1, zupt_data[j, 2], zupt_data[j, 3], zupt_data[j, 4],
                         zupt_data[j, 0], zupt_data[j, 1])
            j -= 1
        # through the transition into k
        tr = st_trans[k]
        if tr == T_MOTION:
            _through_motion(lam, L, t_s[k] - t_s[k - 1])
        elif tr == T_STANDSTILL:
            lam[1] = 0.0
            for a in range(3):
                L[1, a] = 0.0
                L[a, 1] = 0.0
        elif tr == T_RESET:
            for a in range(3):
                lam[a] = 0.0
                for b in range(3):
                    L[a, b] = 0.0
        # T_NONE: Φ = I
