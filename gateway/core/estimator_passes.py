"""The forward and backward passes of the batch filter over a whole recording.

What `estimate_series`'s realtime and smoothed methods (gateway/core/estimator.py, `_filter`)
run on arrays: one forward run of the kernel with the stores the backward pass needs
(`_forward`), the backward smoothing pass (`_smooth_pass`), and the search for stops the
forward pass could not decide, by the same filter run backward from the recording's final
rest (`backward_may_decide`, `stops_seen_from_the_end`). Numbers in, numbers out: the
tracks and notes are assembled by the caller.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from gateway.core import estimator_kernel as K
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.integration import hold_invalid
from gateway.core.reference_point import NoRestError, find_initial_rest
from gateway.core.runs import true_runs
from gateway.core.smoother import run_backward


def _forward(prm, t, z, ok, lost, hint, cols, flags, smooth: bool):
    """One forward run of the kernel into cols/flags; with smooth, the stores the backward
    pass needs: (st_x, st_p, st_trans, st_zaru, zupt_index, zupt_data, n_zupt)."""
    n = t.size
    if smooth:
        st_x, st_p = np.empty((n, 3)), np.empty((n, 6))
        st_trans, st_zaru = np.empty(n, dtype=np.int8), np.empty((n, 2))
        w = max(1, int(prm[K.P_WINDOW]))
        capacity = n // w * 4 + 16 + K.soft_update_bound(hint, w)
    else:
        st_x, st_p = np.empty((1, 3)), np.empty((1, 6))
        st_trans, st_zaru = np.empty(1, dtype=np.int8), np.empty((1, 2))
        capacity = 1
    state = K.new_state(prm)
    for _attempt in range(2):
        zupt_index, zupt_data = np.empty(capacity, dtype=np.int64), np.empty((capacity, 5))
        n_zupt = K.run_forward(prm, t, z, ok, lost, hint, state,
                               cols["pos"], cols["vel"], cols["acc"], cols["bias"], cols["pos_var"],
                               cols["vel_var"], cols["bias_var"], cols["innov"], cols["nis"], cols["zupt"],
                               flags, smooth, st_x, st_p, st_trans, st_zaru, zupt_index, zupt_data)
        if not smooth or n_zupt <= capacity:
            break
        capacity = n_zupt  # rare: more stops than expected; run again with room for all
        state = K.new_state(prm)
    return st_x, st_p, st_trans, st_zaru, zupt_index, zupt_data, n_zupt


def lost_before_reversed(lost_before) -> np.ndarray:
    """The samples lost before each sample of the record read backward: the gap before
    reversed sample j is the one after original sample n−1−j."""
    lost = np.asarray(lost_before, dtype=np.int64)
    return np.concatenate((np.zeros(min(1, lost.size), dtype=np.int64), lost[:0:-1]))


def backward_may_decide(flags) -> bool:
    """The forward pass lost its velocity somewhere (flag 256) and does not know, at the
    end, that the axis moves (it ends in a standstill, or in a quiet stretch it cannot
    decide): a backward run from the end may recognise stops it could not."""
    if not flags.size:
        return False
    init = (flags & K.F_INITIALISED) != 0
    last = int(flags[-1])
    return bool(np.any(init & ((flags & K.F_UNTRUSTED) != 0))
                and (last & K.F_STANDSTILL or last & K.F_UNTRUSTED))


def ends_at_rest(t, z, ok, settings: EstimatorSettings, min_rest_s: float = 0.2, k_sigma: float = 8.0) -> bool:
    """The recording's last min_rest_s (find_initial_rest's shortest rest) stays within
    k_sigma (its bound) of their median on the recording's own noise
    (EstimatorSettings.sample_noise_std_mps2, measured at its initial rest).

    Why: find_initial_rest measures a rest's noise on its own first samples; read from the
    end of a recording scored a tenth of a second into its last rest, those hold the
    sensor's deceleration, the measured spread is the motion's, and the whole recording
    passes for its "final rest" — the backward run then starts inside the last cruise and
    takes it for a stop (the horizontal robot runs: the smoothed estimate's worst move 91 %)."""
    last = np.asarray(z, dtype=float)[t >= t[-1] - min_rest_s]
    last = last[np.asarray(ok, dtype=bool)[t >= t[-1] - min_rest_s]]
    if last.size < 2:
        return False
    return bool(np.all(np.abs(last - np.median(last)) <= k_sigma * settings.sample_noise_std_mps2))


def stops_seen_from_the_end(t, z, ok, lost, hint, settings: EstimatorSettings, forward_flags,
                            cols) -> np.ndarray | None:
    """Stops the forward pass could not decide that the same filter, run backward in time
    from the recording's final rest, recognises: True on their samples (None: none).

    Why: after a long cruise, a gap, or an offset step in the motion, the forward filter
    no longer knows its velocity (or its bias) well enough to call a quiet stretch a stop
    (flag 256). Seen from the other side — from the rest the recording ends in, with the
    bias measured there — the same stretch may be a few seconds from a known standstill,
    and the velocity test decides. The backward run is the realtime filter on the reversed
    record (a body's acceleration is the same read backward in time; its velocity changes
    sign, and the test is on |v|), so its stops carry the same evidence as the forward
    ones. For when the forward pass lost its velocity somewhere and does not know that
    the axis moves at the end (the caller checks backward_may_decide). It starts as the
    forward one does: the recording's end must be a rest of at least 0.2 s
    (find_initial_rest on the reversed record) — the smoothed estimate assumes a
    recording ends at rest as every method assumes it starts at rest (a quiet end that
    is really a cruise would be taken for a rest: documented). The deterministic drift is
    removed first (its model counts time from power-on, forward). cols are scratch space
    here (overwritten by the caller's run).
    """
    fl = np.asarray(forward_flags)
    prm = settings.kernel_params()
    drift = prm[K.P_DRIFT_C1] * -np.expm1(-(t + prm[K.P_DRIFT_T0]) / prm[K.P_DRIFT_T])
    back_prm = replace(settings, drift_c1_mps2=0.0, sensor_lag_s=0.0).kernel_params()
    n = t.size
    ok_back = np.ascontiguousarray(ok[::-1])
    if not ends_at_rest(t, z, ok, settings):
        return None  # the recording does not end at rest as the detector sees one
    try:
        # on the readings as they are: a quantised logger's rest is one value with a
        # flicker (find_initial_rest reads its step), which the drift's removal would blur
        find_initial_rest(z[::-1], ok_back, float(np.median(np.diff(t))))
    except NoRestError:
        return None  # the recording does not end at rest
    z_back = np.ascontiguousarray((z - drift)[::-1])
    flags = np.empty(n, dtype=np.int32)
    _forward(back_prm, np.ascontiguousarray(t[-1] - t[::-1]), z_back, ok_back, lost_before_reversed(lost),
             np.ascontiguousarray(hint[::-1]), cols, flags, False)
    back_still = ((flags & K.F_STANDSTILL) != 0)[::-1]
    forward_still = (fl & K.F_STANDSTILL) != 0
    new = np.zeros(n, dtype=bool)
    for a, b in true_runs(back_still):
        if not forward_still[a:b].any():  # only the stops the forward pass did not see
            new[a:b] = True
    return new if new.any() else None


def _smooth_pass(prm, t, acc, valid, flags, cols, stores) -> None:
    """The backward pass over a forward run's stores: cols become the smoothed estimate."""
    st_x, st_p, st_trans, st_zaru, zupt_index, zupt_data, n_zupt = stores
    n = t.size
    run_backward(t, st_trans, st_x, st_p, st_zaru, prm[K.P_R], zupt_index, zupt_data, n_zupt,
                 cols["pos_var"], cols["vel_var"], cols["bias_var"])
    init = (flags & K.F_INITIALISED) != 0
    still = (flags & K.F_STANDSTILL) != 0
    cols["pos"] = np.where(init, st_x[:, 0], 0.0)
    cols["vel"] = np.where(init, st_x[:, 1], 0.0)
    cols["bias"] = np.where(init, st_x[:, 2], 0.0)
    held = hold_invalid(acc, valid)
    cols["acc"] = np.where(init & ~still, held - cols["bias"], 0.0)
    # undo the sensor filter's lag as the kernel does (kernel_output.write_estimate)
    lag = prm[K.P_LAG]
    moving = init & ~still
    y_edge = np.zeros(n)
    y_edge[1:] = np.where(moving[1:] & moving[:-1], 0.5 * (cols["acc"][1:] + cols["acc"][:-1]), 0.0)
    cols["pos"], cols["vel"] = K.undo_sensor_lag(cols["pos"], cols["vel"], y_edge, lag)
    K.add_scale_position_error(cols["pos_var"], cols["pos"], flags, prm)
    K.add_scale_error(cols["vel_var"], cols["vel"], prm)
    K.add_reading_instant_error(cols["pos_var"], cols["acc"], t, prm)
    _add_disagreement(cols["pos_var"], flags, zupt_index[:n_zupt], zupt_data[:n_zupt], prm)


def _add_disagreement(pos_var, flags, zupt_index, zupt_data, prm) -> None:
    """The realtime estimate's disagreement term (kernel_output.disagreement_var) over a
    smoothed track: from each stop taken on the hint against the integrated velocity, each
    stop or soft hinted update whose velocity innovation is beyond chance
    (kernel_output.zupt_beyond_chance), and each taken on the machine's word on samples that
    still change the velocity (F_HINT_IN_MOTION), on: the square of the position its
    update moved — σ covers both answers."""
    entry = (flags[zupt_index] & K.F_ENTRY) != 0
    soft = (flags[zupt_index] & K.F_HINT_SOFT) != 0
    hint_conflict = (flags[zupt_index] & K.F_HINT_CONFLICT) != 0
    in_motion = (flags[zupt_index] & K.F_HINT_IN_MOTION) != 0
    y, s = zupt_data[:, 0], zupt_data[:, 1]
    beyond = K.zupt_beyond_chance(y, s, prm[K.P_SCALE_VAR], prm[K.P_ZUPT_CHI2])
    conflicted = (entry & hint_conflict) | ((entry | soft) & (beyond | in_motion))
    if not conflicted.any():
        return
    step = np.zeros(pos_var.size)
    # a soft hinted update in motion: the word made exact (kernel_output.exact_update_gain_pos)
    gain_pos = np.array([K.exact_update_gain_pos(k0, k1) if soft_in_motion else k0 for k0, k1, soft_in_motion in
                         zip(zupt_data[conflicted, 2], zupt_data[conflicted, 3], (soft & in_motion)[conflicted],
                             strict=True)])
    np.add.at(step, zupt_index[conflicted], K.disagreement_var(gain_pos, zupt_data[conflicted, 0]))
    pos_var += np.cumsum(step)
