"""How much an accepted effect improves the distance estimate.

An EstimatePlan is what the gateway's estimator (smoothed, offline) is fed: sample
times, the measured acceleration as the extended model corrects it, samples to skip,
setting changes, the machine's standstill hint where the recording has one (as
`adxlgw estimate` uses it by default: a gain or a loss is of the estimate a user gets),
and — for reference_delay — a shift of the reference the error is taken against. The
gain of an effect is the error of the plan without it against the plan with it: at the
stops of a recorded reference (RMS and final), or the final position of a motion that
returns to its start.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gateway.core.diagnosis.context import Prepared
from gateway.core.diagnosis.reading import shifted
from gateway.core.estimator import EstimateTrack, estimate_series
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.evaluation import summarise_errors
from gateway.core.model_compensation import SampleContext, settle_correction
from gateway.core.reference_point import NoRestError


@dataclass
class EstimatePlan:
    settings: EstimatorSettings
    returns_to_start: bool = False
    t_s: np.ndarray | None = None
    acc_mps2: np.ndarray | None = None
    valid: np.ndarray | None = None
    lost_before: np.ndarray | None = None
    ref_shift_s: float = 0.0
    standstill_hint: np.ndarray | None = None  # per sample, as DiagnosisInput.standstill_hint
    # how far the last pass of a correction that needs the estimate still moved the
    # position when its passes did not settle (0: settled, or no such correction)
    unsettled_m: float = 0.0
    _cache: dict = field(default_factory=dict, repr=False)

    def run(self, t_s, acc, valid, lost) -> EstimateTrack:
        return estimate_series(t_s, acc, valid, method="smoothed", settings=self.settings, lost_before=lost,
                               standstill_hint=self.standstill_hint)

    def baseline(self, data) -> EstimatePlan:
        return EstimatePlan(self.settings, self.returns_to_start, data.t_s, data.acc_mps2, data.valid.copy(),
                            data.lost_before, standstill_hint=data.standstill_hint)

    def _copy(self, **changes) -> EstimatePlan:
        return replace(self, _cache={}, **changes)

    def track(self, prep: Prepared) -> EstimateTrack | None:
        if "track" not in self._cache:
            try:
                self._cache["track"] = self.run(self.t_s, self.acc_mps2, self.valid, self.lost_before)
            except NoRestError:
                self._cache["track"] = None
        return self._cache["track"]

    def with_signal(self, prep: Prepared, fit, effects) -> EstimatePlan:
        """The baseline plan corrected by each accepted signal effect, in order of acceptance."""
        plan = self._base_of_chain(prep)
        for e in effects:
            theta, _ = fit.effect_theta(e)
            plan = self._compensated(prep, plan, e, theta)
        return plan

    def _compensated(self, prep: Prepared, plan: EstimatePlan, effect, theta) -> EstimatePlan:
        """The plan corrected for one effect. An effect that needs the estimate (tilt: its
        position; motion_offset: where it moves) is corrected with the estimate's own,
        re-estimated until it settles (model_compensation.settle_correction: the one loop,
        `adxlgw estimate --model` runs the same): the estimate without the correction can
        be metres off, and one pass from there overshoots. Where the passes do not settle
        the plan carries `unsettled_m`, and its distance gain is not determined
        (distance_gain)."""
        if not getattr(effect, "uses_position", False):
            return plan.apply(effect.compensate(prep, theta, plan.acc_mps2, self._context(prep, plan.track(prep))))

        def correct(track) -> np.ndarray:
            return effect.compensate(prep, theta, plan.acc_mps2, self._context(prep, track)).acc_mps2

        result = settle_correction(correct, lambda acc: plan._copy(acc_mps2=acc).track(prep), start=plan.track(prep))
        new = plan._copy(acc_mps2=result.acc_mps2)
        new._cache["track"] = result.track
        if result.track is not None and not result.settled:
            new.unsettled_m = max(new.unsettled_m, result.last_step_m)
        return new

    @staticmethod
    def _context(prep: Prepared, track) -> SampleContext:
        """What a correction may use: the record's columns and the estimate's position and motion."""
        d = prep.data
        n = len(d)
        return SampleContext(d.t_s, d.other_mps2, d.temperature_c,
                             pos_m=track.pos_m if track is not None else np.zeros(n),
                             moving=~np.asarray(track.standstill, bool) if track is not None else np.zeros(n, bool),
                             rest=prep.rest)

    def _base_of_chain(self, prep: Prepared) -> EstimatePlan:
        d = prep.data
        return EstimatePlan(self.settings, self.returns_to_start, d.t_s, d.acc_mps2, d.valid.copy(), d.lost_before,
                            standstill_hint=d.standstill_hint)

    def apply(self, comp) -> EstimatePlan:
        if comp is None:
            return self
        acc = self.acc_mps2 if comp.acc_mps2 is None else comp.acc_mps2
        valid = self.valid if comp.invalid is None else (self.valid & ~comp.invalid)
        settings = self.settings
        s = dict(comp.settings)
        if "scale" in s:
            acc = acc * s.pop("scale")
        if "extra_sensor_lag_s" in s:
            settings = replace(settings, sensor_lag_s=settings.sensor_lag_s + s.pop("extra_sensor_lag_s"))
        if "bias_random_walk_mps2_per_rts" in s:
            k = max(settings.bias_random_walk_mps2_per_rts, s.pop("bias_random_walk_mps2_per_rts"))
            settings = replace(settings, bias_random_walk_mps2_per_rts=k)
        return self._copy(acc_mps2=acc, valid=valid, settings=settings,
                          ref_shift_s=self.ref_shift_s + comp.ref_shift_s)

    def with_side(self, prep: Prepared, effect, test) -> EstimatePlan:
        return self.apply(test.compensation)

    def as_host_timed(self, prep: Prepared) -> EstimatePlan:
        """What trusting the host's arrival times instead of the board's T2 clock gives."""
        d = prep.data
        host = d.t_host_s - d.t_host_s[0] + d.t_s[0]
        host = np.maximum.accumulate(host + np.arange(host.size) * 1e-9)  # strictly increasing
        return self._copy(t_s=host, lost_before=np.zeros(host.size, dtype=np.int64))

    def as_gapless(self, prep: Prepared) -> EstimatePlan:
        """What a model that loses no samples makes of the record: gaps closed up."""
        d = prep.data
        t = d.t_s - np.cumsum(d.lost_before) * d.period_s
        return self._copy(t_s=t, lost_before=np.zeros(t.size, dtype=np.int64))


def _errors(prep: Prepared, plan: EstimatePlan) -> dict | None:
    track = plan.track(prep)
    if track is None:
        return None
    d = prep.data
    if d.reference == "recorded" and d.ref_pos_m is not None:
        t = d.t_s
        ref_pos = shifted(t, d.ref_pos_m, plan.ref_shift_s)
        ref_vel = shifted(t, d.ref_vel_mps, plan.ref_shift_s)
        # the plan's time axis may differ (host time, gaps closed): compare sample by sample
        s = summarise_errors(t, track.pos_m, ref_pos, ref_vel)
        stops = np.array([st.error_m for st in s.stops])
        # what the estimator itself says it knows each stop's position to (judgement.matters)
        std = np.array([track.pos_std_m[st.index] for st in s.stops], dtype=float)
        return {"stop_rms_mm": float(np.sqrt(np.mean(stops**2))) * 1e3 if stops.size else float("nan"),
                "final_mm": s.final_m * 1e3, "rms_mm": s.rms_m * 1e3, "stops_mm": (stops * 1e3).tolist(),
                "stop_std_mm": float(np.sqrt(np.mean(std**2))) * 1e3 if std.size else float("nan")}
    if plan.returns_to_start:
        return {"final_mm": float(track.pos_m[-1]) * 1e3, "stop_std_mm": float(track.pos_std_m[-1]) * 1e3}
    return None


def distance_gain(prep: Prepared, before: EstimatePlan, after: EstimatePlan) -> dict:
    """The distance error before and after a change, and the improvement (mm) — measured
    only where each side is one answer. A correction that needs the estimate and did not
    settle (`unsettled_m`, either side: a chain carries it on) leaves the distance one of
    the answers its passes alternate between; a gain taken from it would be chance, so it
    is "not determined" (`determined: false`, `available: false`, `unsettled_mm`): every
    reader of `available` (judgement.matters, the report, the benchmarks) counts it
    neither for nor against (docs/diagnosis.md §6)."""
    b, a = _errors(prep, before), _errors(prep, after)
    if b is None or a is None:
        why = ("no reference and not known to return to its start (--returns-to-start)"
               if prep.data.reference != "recorded" and not before.returns_to_start
               else "the estimator found no standstill to start from")
        return {"available": False, "determined": False, "why": why}
    key = "stop_rms_mm" if "stop_rms_mm" in b and math.isfinite(b["stop_rms_mm"]) else "final_mm"
    unsettled_m = max(before.unsettled_m, after.unsettled_m)
    if unsettled_m > 0:
        return {"available": False, "determined": False, "metric": key, "before": b, "after": a,
                "unsettled_mm": unsettled_m * 1e3,
                "why": f"not determined (the correction's passes differ by {unsettled_m * 1e3:.1f} mm)"}
    return {"available": True, "determined": True, "metric": key, "before": b, "after": a,
            "improvement_mm": abs(b[key]) - abs(a[key])}
