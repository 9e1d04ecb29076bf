"""Distance and velocity from the accelerometer: the estimators behind `adxlgw estimate` and the daemon.

Methods (estimate_series):
    raw       double integration of the measured acceleration, nothing removed (paper fig. 6)
    paper     reference-point compensation + the paper's 3-state Kalman filter (fig. 7)
    realtime  the gateway's filter (estimator_kernel): bias state driven by the drift model,
              standstill detector, ZUPT/ZARU, position held at rest — causal
    smoothed  the same filter plus the backward pass (smoother) — for recordings; where the
              forward pass lost its velocity, its stops are also sought from the
              recording's end (estimator_passes.stops_seen_from_the_end)

The daemon uses RealtimeEstimator one sample at a time; it runs the very same step as
estimate_series(method="realtime").
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field, replace

import numpy as np

from gateway.core import estimator_kernel as K
from gateway.core.estimator_passes import _forward, _smooth_pass, backward_may_decide, stops_seen_from_the_end
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.hint_latency import aligned_hint, hint_latency
from gateway.core.integration import double_integrate, hold_invalid
from gateway.core.kalman_paper import DEFAULT_JERK_DENSITY, run_paper_filter
from gateway.core.reference_point import NoRestError, find_initial_rest
from gateway.core.runs import true_runs

METHODS = ("raw", "paper", "realtime", "smoothed")
# judged beside `smoothed` on the corpus (benchmarks/accuracy/estimation_corpus.py --compare) and
# selectable from `adxlgw estimate --method`
COMPARED_METHODS = ("zupt", "zupt-forward")


# the flags that make an estimate's numbers the last ones, not live (Estimate.holding)
HOLDING_FLAGS = K.F_INPUT_INVALID | K.F_TIME_ERROR


# what an Estimate reads of the kernel's output, with one call
_KERNEL_OUTPUTS = operator.itemgetter(K.O_POS, K.O_VEL, K.O_ACC, K.O_BIAS, K.O_POS_VAR, K.O_VEL_VAR, K.O_INNOV,
                                      K.O_NIS, K.O_ZUPT_INNOV, K.O_ZUPT_NIS, K.O_FLAGS)


# not frozen: a frozen dataclass's __init__ sets each of the 12 fields through
# object.__setattr__, and the daemon builds one per published change, read by every
# wire's snapshot — on a VM cold at each wakeup (docs/decisions/0154)
@dataclass(slots=True)
class Estimate:
    """One sample's estimate and the health the daemon publishes: the one estimate type
    (the realtime estimator, the daemon's pipeline and every wire read this).

    Read only: no one changes an estimate once built (nothing assigns to one or hashes
    one; the pipeline caches the newest and builds a new one when it changes). The rule
    is said, not enforced, as for PublishedValues."""

    t_s: float
    pos_m: float
    vel_mps: float
    acc_mps2: float
    bias_mps2: float
    pos_std_m: float
    vel_std_mps: float
    innovation_mps2: float  # z − b at standstill (ZARU), 0 in motion
    nis: float  # innovation² / its variance (χ², 1 dof, at standstill), 0 in motion
    zupt_velocity_error_mps: float  # velocity found at the latest stop (ZUPT innovation, held)
    zupt_nis: float
    flags: int  # estimator_kernel.F_*

    @classmethod
    def from_kernel(cls, t_s: float, out: np.ndarray, reference_m: float = 0.0,
                    held_std_unknown: bool = False) -> Estimate:
        """The estimate in a kernel output array (`KernelState.out`, layout O_*), the
        position measured from `reference_m`. With `held_std_unknown`, the position's σ
        is NaN before the filter has initialised (the position is held there, not
        estimated, and the kernel's variance 0 would claim it exact)."""
        return cls.from_kernel_values(t_s, out.tolist(), reference_m, held_std_unknown)

    @classmethod
    def from_kernel_values(cls, t_s: float, o: list[float], reference_m: float = 0.0,
                           held_std_unknown: bool = False) -> Estimate:
        """`from_kernel` of the output array as a list (`out.tolist()`: one conversion, not
        twelve numpy scalars), for a caller that reads or changes it first."""
        pos, vel, acc, bias, pos_var, vel_var, innov, nis, zupt_innov, zupt_nis, flags = _KERNEL_OUTPUTS(o)
        flags = int(flags)
        pos_std = math.sqrt(pos_var) if pos_var >= 0.0 else math.nan
        if held_std_unknown and not flags & K.F_INITIALISED:
            pos_std = math.nan
        return cls(float(t_s), pos - reference_m, vel, acc, bias, pos_std,
                   math.sqrt(vel_var) if vel_var >= 0.0 else math.nan, innov, nis, zupt_innov, zupt_nis, flags)

    @property
    def standstill(self) -> bool:
        return bool(self.flags & K.F_STANDSTILL)

    @property
    def initialised(self) -> bool:
        """False before the first standstill: the bias is unknown and the position held at 0."""
        return bool(self.flags & K.F_INITIALISED)

    @property
    def input_invalid(self) -> bool:
        """The sample's acceleration was unusable; the estimate holds."""
        return bool(self.flags & K.F_INPUT_INVALID)

    @property
    def gap(self) -> bool:
        return bool(self.flags & K.F_GAP)

    @property
    def holding(self) -> bool:
        """The numbers are the last ones, not live: no valid input, or time did not advance."""
        return bool(self.flags & HOLDING_FLAGS)

    @property
    def fault(self) -> bool:
        """The filter's state is not finite or diverged: the numbers mean nothing."""
        return bool(self.flags & K.F_FAULT)

    @property
    def bias_estimating(self) -> bool:
        return bool(self.flags & K.F_BIAS_ESTIMATING)

    @property
    def untrusted(self) -> bool:
        """Position not trustworthy now: the estimator cannot tell a cruise from a stop."""
        return bool(self.flags & K.F_UNTRUSTED)


class RealtimeEstimator:
    """Causal estimator: one sample in, one estimate out — a thin wrapper of the kernel's
    state (`estimator_kernel.KernelState`) and its `step`.

    step(t_s, acc) with acc None (or NaN/inf) for an invalid sample, lost_before for
    samples lost on the line before this one. tare() sets the position to zero;
    request_bias_reestimate() forgets the bias so the next standstill measures it anew
    (e.g. after a temperature step); reset() starts over (board reset).
    """

    def __init__(self, settings: EstimatorSettings):
        self.settings = settings
        self.params = settings.kernel_params()
        self.reset()

    def reset(self) -> None:
        self.state: K.KernelState = K.new_state(self.params)

    def restart(self) -> None:
        """Start over after a board reset or a restart that may come mid-move: unlike reset(),
        the first quiet window is not taken as a rest (it may be a cruise). The filter starts
        in motion with the velocity unknown (restart_speed_std_mps) and the position flagged
        not trustworthy until a stop is recognised on evidence: the machine's rest hint, or a
        quiet stretch longer than any cruise can last (EstimatorSettings.quiet_stop_s)."""
        self.reset()
        K.mark_velocity_unknown(self.state)

    def step(self, t_s: float, acc_mps2: float | None, lost_before: int = 0) -> Estimate:
        valid = acc_mps2 is not None
        K.step(self.state, self.params, float(t_s), float(acc_mps2) if valid else 0.0, valid, int(lost_before))
        return Estimate.from_kernel(t_s, self.state.out)

    def set_travel_span(self, travel_span_m: float) -> None:
        """The axis's travel from now on (highest − lowest position, m): it bounds how long a
        cruise can last, so how long an undecidable quiet stretch must be to be a stop
        (EstimatorSettings.quiet_stop_s). The state is kept."""
        self.settings = replace(self.settings, travel_span_m=float(travel_span_m))
        self.params[:] = self.settings.kernel_params()

    def set_hint(self, hint: float | None) -> None:
        """The machine's standstill hint from now on: 1 at rest, 0 moving, None unknown
        (set None when a wire's hint expires). Evidence, not an order: a rest hint while
        a window of the accelerometer shows motion is flagged (F_HINT_CONFLICT), not obeyed."""
        K.set_hint(self.state, hint)

    def tare(self) -> None:
        K.tare(self.state)

    def request_bias_reestimate(self) -> None:
        K.request_bias_reestimate(self.state, self.params)

    @property
    def position_untrusted(self) -> bool:
        """The position is not trustworthy now — known before the next step too (right after
        restart(), before any sample: the axis may be moving)."""
        return bool(self.state.misc[K.M_UNTRUSTED] > 0.0)

    @property
    def covariance(self) -> np.ndarray:
        """Copy of the state covariance of [position, velocity, bias]."""
        return self.state.P.copy()


@dataclass
class EstimateTrack:
    """An estimate per sample, as arrays (columns of `adxlgw estimate --out`)."""

    method: str
    t_s: np.ndarray
    pos_m: np.ndarray
    vel_mps: np.ndarray
    acc_mps2: np.ndarray
    bias_mps2: np.ndarray
    pos_std_m: np.ndarray
    vel_std_mps: np.ndarray
    innovation_mps2: np.ndarray
    nis: np.ndarray
    zupt_velocity_error_mps: np.ndarray
    flags: np.ndarray
    notes: list[str] = field(default_factory=list)  # what could not be done, for the command

    def __len__(self) -> int:
        return self.t_s.size

    @property
    def standstill(self) -> np.ndarray:
        return (self.flags & K.F_STANDSTILL) != 0

    @property
    def initialised(self) -> np.ndarray:
        return (self.flags & K.F_INITIALISED) != 0

    @property
    def untrusted(self) -> np.ndarray:
        """Position not trustworthy: a quiet stretch may be a cruise or a stop (F_UNTRUSTED)."""
        return (self.flags & K.F_UNTRUSTED) != 0

    def columns(self) -> dict[str, np.ndarray]:
        return {
            "t_s": self.t_s,
            "pos_m": self.pos_m,
            "vel_mps": self.vel_mps,
            "acc_mps2": self.acc_mps2,
            "standstill": self.standstill.astype(np.int64),
            "bias_mps2": self.bias_mps2,
            "pos_std_m": self.pos_std_m,
            "vel_std_mps": self.vel_std_mps,
            "innovation_mps2": self.innovation_mps2,
            "nis": self.nis,
            "zupt_velocity_error_mps": self.zupt_velocity_error_mps,
            "flags": self.flags.astype(np.int64),
        }


def lost_from_times(t_s) -> np.ndarray:
    """Samples missing before each one, from gaps in the time axis (> 1.5 median periods)."""
    t = np.asarray(t_s, dtype=float)
    lost = np.zeros(t.size, dtype=np.int64)
    if t.size > 2:
        dt = np.diff(t)
        period = float(np.median(dt))
        gap = dt > 1.5 * period
        lost[1:][gap] = np.rint(dt[gap] / period).astype(np.int64) - 1
    return lost


def _input_flags(valid, lost) -> np.ndarray:
    flags = np.where(valid, 0, K.F_INPUT_INVALID) | np.where(lost > 0, K.F_GAP, 0)
    return flags.astype(np.int32)


def _track(method, t, pos, vel, acc, bias, pos_var, vel_var, innov, nis, zupt, flags, notes) -> EstimateTrack:
    return EstimateTrack(
        method=method, t_s=t, pos_m=pos, vel_mps=vel, acc_mps2=acc, bias_mps2=bias,
        pos_std_m=np.sqrt(np.maximum(pos_var, 0.0)), vel_std_mps=np.sqrt(np.maximum(vel_var, 0.0)),
        innovation_mps2=innov, nis=nis, zupt_velocity_error_mps=zupt, flags=flags, notes=notes,
    )


def _raw(t, acc, valid, lost, notes) -> EstimateTrack:
    pos, vel = double_integrate(t, acc, valid)
    n = t.size
    zeros = np.zeros(n)
    flags = _input_flags(valid, lost) | K.F_INITIALISED
    return _track("raw", t, pos, vel, hold_invalid(acc, valid), zeros, zeros, zeros, zeros, zeros, zeros,
                  flags, notes)


def _paper(t, acc, valid, lost, period, jerk_density, notes) -> EstimateTrack:
    try:
        rest = find_initial_rest(acc, valid, period)
    except NoRestError as err:
        raise NoRestError(f"reference-point compensation needs an initial standstill: {err}",
                          moves_after_s=err.moves_after_s) from None
    compensated = acc - rest.offset_mps2
    states, pos_var = run_paper_filter(t, compensated, valid, jerk_density, max(rest.sample_std_mps2, 1e-9) ** 2)
    n = t.size
    zeros = np.zeros(n)
    flags = _input_flags(valid, lost) | K.F_INITIALISED
    notes.append(f"reference point: {rest.samples} samples at rest, offset {rest.offset_mps2:.6g} m/s²")
    return _track("paper", t, states[:, 0], states[:, 1], states[:, 2], np.full(n, rest.offset_mps2), pos_var,
                  zeros, zeros, zeros, zeros, flags, notes)


def _filter(t, acc, valid, lost, hint, settings: EstimatorSettings, smooth: bool, notes) -> EstimateTrack:
    prm = settings.kernel_params()
    n = t.size
    cols = {name: np.empty(n) for name in ("pos", "vel", "acc", "bias", "pos_var", "vel_var", "bias_var",
                                           "innov", "nis", "zupt")}
    flags = np.empty(n, dtype=np.int32)
    z = np.where(valid, acc, 0.0)
    ok = np.asarray(valid, dtype=np.bool_)
    lost = np.asarray(lost, dtype=np.int64)
    stores = _forward(prm, t, z, ok, lost, hint, cols, flags, smooth)
    if not smooth:
        return _track("realtime", t, cols["pos"], cols["vel"], cols["acc"], cols["bias"], cols["pos_var"],
                      cols["vel_var"], cols["innov"], cols["nis"], cols["zupt"], flags, notes)
    one_pass = None  # the one-pass answer where the forward pass could not decide, if the end is only assumed a rest
    if backward_may_decide(flags):
        if not flags[-1] & K.F_STANDSTILL:
            _smooth_pass(prm, t, acc, valid, flags, cols, stores)
            one_pass = ((flags & K.F_UNTRUSTED) != 0, cols["pos"].copy(), cols["pos_var"].copy(),
                        cols["vel"].copy(), cols["vel_var"].copy())
        # the forward stores go first: the backward run's reversed copies then fit in
        # their room (commands/estimate.SMOOTHED_BYTES_PER_SAMPLE)
        del stores
        seen = stops_seen_from_the_end(t, z, ok, lost, hint, settings, flags, cols)
        # the backward run's stops enter the forward pass as a rest hint where the machine
        # gave none: evidence the forward pass still checks (kernel_standstill_judge.hint_gate), not
        # an order; the hint's own flags there are not the machine's
        derived = np.zeros(n, dtype=bool) if seen is None else seen & ~np.isfinite(hint)
        stores = _forward(prm, t, z, ok, lost, np.where(derived, 1.0, hint), cols, flags, smooth)
        flags[derived] &= ~np.int32(K.F_HINT_REST | K.F_HINT_CONFLICT | K.F_HINT_SOFT)
        if not derived.any():
            one_pass = None
        else:
            notes.append(f"{len(true_runs(derived))} stop(s) the forward pass could not decide were recognised "
                         f"running backward from the final rest ({int(np.count_nonzero(derived))} samples): "
                         "the smoothed estimate uses them" + (
                             "; the recording's end was taken for a rest, which the forward pass could not "
                             "confirm: where it could not decide, the position stays flagged (256) and its "
                             "uncertainty covers the estimate without those stops" if one_pass is not None else ""))
    _smooth_pass(prm, t, acc, valid, flags, cols, stores)
    del stores
    if one_pass is not None:
        # two answers — the end a rest (the stops seen from it), or not (the one-pass
        # smoother) — and no evidence to choose: the first is given, flagged, with an
        # uncertainty that covers both (the larger variance plus their squared difference)
        untrusted, pos1, pos_var1, vel1, vel_var1 = one_pass
        flags[untrusted] |= np.int32(K.F_UNTRUSTED)
        cols["pos_var"] = np.where(untrusted, np.maximum(cols["pos_var"], pos_var1) + (cols["pos"] - pos1) ** 2,
                                   cols["pos_var"])
        cols["vel_var"] = np.where(untrusted, np.maximum(cols["vel_var"], vel_var1) + (cols["vel"] - vel1) ** 2,
                                   cols["vel_var"])
    return _track("smoothed", t, cols["pos"], cols["vel"], cols["acc"], cols["bias"], cols["pos_var"],
                  cols["vel_var"], cols["innov"], cols["nis"], cols["zupt"], flags, notes)


def _zupt_smoothed(t, acc, valid, lost, hint, settings: EstimatorSettings, notes,
                   forward_only: bool = False) -> EstimateTrack:
    """The offline ZUPT smoother (zupt_smoother) as a track: its rests, its flags, the
    reported σ with the terms the model cannot see (as the realtime filter's).
    `forward_only` ("zupt-forward"): its rests decided from their start alone and no
    backward pass — what a realtime estimator with its detector would publish."""
    from gateway.core.zupt_smoother import smooth

    res = smooth(t, acc, valid, lost, settings, hint=hint if np.isfinite(hint).any() else None,
                 forward_only=forward_only)
    n = t.size
    prm = settings.kernel_params()
    entry = np.zeros(n, dtype=bool)
    entry[1:] = res.rest[1:] & ~res.rest[:-1]
    entry[0] = res.rest[0]
    flags = (_input_flags(valid, lost) | K.F_INITIALISED | np.where(res.rest, K.F_STANDSTILL, 0)
             | np.where(entry, K.F_ENTRY, 0) | np.where(res.untrusted, K.F_UNTRUSTED, 0)).astype(np.int32)
    acc_out = np.where(res.rest, 0.0, hold_invalid(acc, valid) - res.bias_mps2)
    moving = ~res.rest
    y_edge = np.zeros(n)
    y_edge[1:] = np.where(moving[1:] & moving[:-1], 0.5 * (acc_out[1:] + acc_out[:-1]), 0.0)
    pos, vel = K.undo_sensor_lag(res.pos_m, res.vel_mps, y_edge, prm[K.P_LAG])
    # the lag's correction rests on the one-pole model of the sensor's filter: its own size
    # is carried as its uncertainty (a model off entirely would leave all of it)
    pos_var = res.pos_var + (pos - res.pos_m) ** 2  # the position's gain term is per move (zupt_smoother)
    vel_var = res.vel_var + (vel - res.vel_mps) ** 2
    K.add_scale_error(vel_var, vel, prm)
    K.add_reading_instant_error(pos_var, acc_out, t, prm)
    zeros = np.zeros(n)
    method = "zupt-forward" if forward_only else "zupt"
    return _track(method, t, pos, vel, acc_out, res.bias_mps2, pos_var, vel_var, zeros, zeros, zeros, flags,
                  notes)


@dataclass
class RunCounts:
    """What a run of the filter over a recording met, summed over one or many chunks, and
    the notes `adxlgw estimate` prints about it (the same whether the run was whole or
    streamed)."""

    invalid: int = 0
    gaps: int = 0
    lost: int = 0
    samples: int = 0
    hint_conflicts: int = 0
    untrusted: int = 0
    t0: float | None = None
    t_first_untrusted: float | None = None
    first_init: int = -1
    t_first_init: float | None = None

    def add_input(self, ok, lost) -> None:
        self.invalid += int(np.count_nonzero(~ok))
        self.gaps += int(np.count_nonzero(lost))
        self.lost += int(np.sum(lost))

    def add_output(self, t, flags) -> None:
        if t.size and self.t0 is None:
            self.t0 = float(t[0])
        self.hint_conflicts += int(np.count_nonzero(flags & K.F_HINT_CONFLICT))
        untrusted = (flags & K.F_UNTRUSTED) != 0
        if self.t_first_untrusted is None and untrusted.any():
            self.t_first_untrusted = float(t[int(np.argmax(untrusted))])
        self.untrusted += int(np.count_nonzero(untrusted))
        init = (flags & K.F_INITIALISED) != 0
        if self.first_init < 0 and init.any():
            k = int(np.argmax(init))
            self.first_init = self.samples + k
            self.t_first_init = float(t[k])
        self.samples += t.size

    def input_notes(self) -> list[str]:
        notes = []
        if self.invalid:
            notes.append(f"{self.invalid} samples invalid (NaN/inf/flagged): the estimate holds over them")
        if self.lost:
            notes.append(f"{self.gaps} gaps, {self.lost} samples lost: "
                         "bridged between the valid samples either side, with their difference as uncertainty")
        return notes

    def outcome_notes(self) -> list[str]:
        notes = []
        if self.hint_conflicts:
            notes.append(f"{self.hint_conflicts} samples hinted 'at rest' while the accelerometer shows motion: "
                         "hint not obeyed there")
        if self.untrusted:
            notes.append(f"position not trustworthy for {self.untrusted} samples "
                         f"({100.0 * self.untrusted / max(self.samples, 1):.0f} %; from "
                         f"{self.t_first_untrusted - self.t0:.3f} s): a quiet stretch there may be a cruise or "
                         "a stop (flag 256)")
        if self.first_init > 0:
            notes.append(f"the first {self.first_init} samples ({self.t_first_init - self.t0:.3f} s) came before "
                         "the first standstill: held at position 0")
        return notes


def estimate_series(t_s, acc_mps2, valid=None, method: str = "realtime",
                    settings: EstimatorSettings | None = None, lost_before=None,
                    known_bias_mps2=None, jerk_density: float = DEFAULT_JERK_DENSITY,
                    standstill_hint=None, align_hint: bool = False) -> EstimateTrack:
    """Estimate position and velocity for every sample of a recording.

    valid: False where the sample is unusable (NaN/inf are invalid anyway).
    lost_before: samples lost before each one (from seq gaps); None → from time gaps.
    standstill_hint: the machine's word per sample — 1 at rest, 0 moving, NaN unknown
        (realtime and smoothed only; evidence, not an order: kernel_standstill_judge.hint_gate).
        Its latency against the accelerometer's own edges is measured and reported in the
        notes (hint_latency); align_hint: shift the hint by it before use (off by default:
        docs/decisions/0120-hint-latency-measured-not-applied.md).
    known_bias_mps2: the true bias per sample (simulation only) — the noise floor: the
        realtime/smoothed filter is fed z − b_true and told the bias is exactly zero.
    Raises NoRestError when nothing can be estimated (no standstill to start from).
    """
    if method not in METHODS + COMPARED_METHODS:
        raise ValueError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    t = np.ascontiguousarray(t_s, dtype=float)
    acc = np.ascontiguousarray(acc_mps2, dtype=float)
    if t.size != acc.size:
        raise ValueError("t_s and acc_mps2 differ in length")
    if t.size < 2:
        raise NoRestError("fewer than two samples")
    ok = np.isfinite(acc) if valid is None else (np.asarray(valid, dtype=bool) & np.isfinite(acc))
    lost = lost_from_times(t) if lost_before is None else np.asarray(lost_before, dtype=np.int64)
    counts = RunCounts()
    counts.add_input(ok, lost)
    notes: list[str] = counts.input_notes()
    period = float(np.median(np.diff(t)))
    bursts = int(np.count_nonzero(np.diff(t) < 0.5 * period))
    if bursts:
        # the filter takes the times as the samples' true times; a logger's arrival times
        # (backlogs flushed in bursts) are not, and no flag can see that from the samples
        notes.append(f"{bursts} sample intervals are under half the median period ({period * 1e3:.3g} ms): "
                     "these look like arrival times, not sample times — the estimate assumes true "
                     "sample times (re-time them first)")
    if method == "raw":
        return _raw(t, acc, ok, lost, notes)
    if method == "paper":
        return _paper(t, acc, ok, lost, period, jerk_density, notes)
    if settings is None:
        raise ValueError("the realtime and smoothed methods need EstimatorSettings")
    if known_bias_mps2 is not None:
        acc = acc - np.asarray(known_bias_mps2, dtype=float)
        settings = settings.with_known_bias()
    if standstill_hint is None:
        hint = np.full(t.size, np.nan)
    else:
        hint = np.ascontiguousarray(standstill_hint, dtype=float)
        if hint.size != t.size:
            raise ValueError("standstill_hint and t_s differ in length")
        latency = hint_latency(t, acc, ok, hint, settings.standstill_false_motion_prob)
        notes.append(latency.describe(applied=align_hint))
        if align_hint and latency.lag_s is not None:
            hint = aligned_hint(t, hint, latency.lag_s)
    if method in COMPARED_METHODS:
        track = _zupt_smoothed(t, acc, ok, lost, hint, settings, notes, forward_only=method == "zupt-forward")
    else:
        track = _filter(t, acc, ok, lost, hint, settings, method == "smoothed", notes)
    init = track.initialised
    if not init.any():
        raise NoRestError(
            "no standstill found: the estimator needs a quiet stretch of "
            f"{settings.window_samples} valid samples ({settings.standstill_window_s:g} s) to measure the bias"
        )
    counts.add_output(t, track.flags)
    notes += counts.outcome_notes()
    return track
