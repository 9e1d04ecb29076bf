"""The estimator kernel's named layout: the parameters (P_*, EstimatorSettings.kernel_params),
the filter's memory (M_*, the snapshot ring), the output (O_*), the health flags (F_*), the
regimes and transitions; the state record (KernelState) and what a caller may do to it
between samples (new_state, tare, set_hint, …).

The state is a NamedTuple of preallocated arrays, the scalars of `misc` by named index
(M_*): numba compiles the per-sample step over it without allocation, caches it to disk,
and every caller — Python, the offline loop, the daemon's compiled loop — holds the same
value. The per-sample records (StandstillDecision, UpdateRecord) are NamedTuples of
scalars: inlined into the step they live in registers, nothing is built on the heap. A
jitclass would name the fields too, but numba does not cache jitclass code to disk
(every start would compile); a structref is itself reference-counted, and its array
fields would be counted at each read — the cost the step is compiled without
(jit.jit_without_refcounts). See docs/decisions/0125-kernel-phases-and-records.md.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from gateway.core.jit import jit

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
# the input held before M_U_PREV (sample k−2's mean; = M_U_PREV when there is none): with
# sample k's, the range that bounds how the acceleration moved inside period k−1
M_U_PREV2 = 27
# the moves since the tare, for the sensitivity's share of the position's variance
# (kernel_output.scale_position_var): Σ Δp² over the moves closed by a stop, and the
# position of the latest stop (where the current move began)
M_MOVES_SQ = 28
M_LAST_STOP_POS = 29
N_MISC = 30

# snapshot ring (one row per sample of the last window): x, P (00 01 02 11 12 22), t,
# and the sample's input: z, valid, lost_before; the input held before it (M_U_PREV2 after it)
N_SNAP = 14

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
# a velocity update on the machine's word (a hinted stop, a soft hinted update) taken on samples whose
# acceleration still changes the velocity beyond the noise: when the axis stood still is not known from
# them, and σ covers the position with and without the update (standstill.velocity_changes_beyond_noise)
F_HINT_IN_MOTION = 32768

# a velocity beyond this is no motion of any machine the sensor rides on: the filter diverged
DIVERGED_SPEED_MPS = 1000.0


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
    state.misc[M_MOVES_SQ] = 0.0
    state.misc[M_LAST_STOP_POS] = 0.0


def request_bias_reestimate(state: KernelState, prm: np.ndarray) -> None:
    """Widen the bias variance back to its initial value: the next standstill re-measures
    it (and `F_BIAS_ESTIMATING` is set until a standstill begins)."""
    state.P[2, 2] = max(state.P[2, 2], prm[P_BIAS0_VAR])
    state.misc[M_BIAS_REQUESTED] = 1.0


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
