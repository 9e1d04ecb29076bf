"""The diagnosis: baseline, look, add effects one at a time, judge, measure the gain.

Selection (signal effects on the measured axis), forward:
  1. fit the baseline (offset + drift) and the ARMA(1,1) noise model on the rests;
  2. fit every remaining candidate jointly with those already accepted, starting from
     its own quick fit on the current residual;
  3. take the best by BIC; accept it only if ΔBIC ≤ −BIC_MARGIN *and* its
     likelihood-ratio test has p < ALPHA (Bonferroni over the candidates of the round);
     otherwise stop.
Side effects (other axis, host clock, seq gaps, bias wander) are each tested once with
their own likelihood ratio, the bias wander on the final residual.
"Unexplained" is set when the final residual is still not white: structure remains that
no candidate explains — said rather than naming a wrong cause.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.stats import chi2

from gateway.core.diagnosis.context import DiagnosisInput, Prepared, prepare
from gateway.core.diagnosis.gain import distance_gain, EstimatePlan
from gateway.core.diagnosis.judgement import (
    distance_loss_is_chance, matters, physical, residual_share, setup_range,
)
from gateway.core.diagnosis.model_fit import ModelFit, fit_model, out_of_sample_gain
from gateway.core.diagnosis.reading import fit_noise_model
from gateway.core.diagnosis.screening import (
    allan_slopes, block_whiteness_p, candidate_regressors, correlations, spectrum_peaks,
)
from gateway.core.diagnosis.side_effects import SIDE_EFFECTS, SideEffect, SideTest
from gateway.core.diagnosis.signal_effects import SIGNAL_EFFECTS, Signal, SignalEffect
from gateway.core.diagnosis.timestamps import HostClock, check_host_clock, check_sample_clock
from gateway.core.estimator_settings import EstimatorSettings

BIC_MARGIN = 10.0  # "very strong" evidence on Kass & Raftery's scale
ALPHA = 1e-3  # per round, split over the candidates tried
# cross-validation: the effect fitted on one half must raise the other half's
# log-likelihood, both ways. Not by a margin: each half's offset and drift are refitted
# there, and they take a slow effect's share (a temperature swing over the record is
# nearly a line on each half: gains of 1–3 for an effect with ΔBIC −38); a shape fitted
# to a mismatch loses tens to hundreds out of sample
CV_MIN_GAIN = 0.0
# ...judged only on a half where the effect reaches far enough beyond offset and drift
# to decide (model_fit.out_of_sample_gain: a right effect gains ~reach/2 ± √reach, a wrong
# one loses as much; the sign is 2σ clear from reach 16 on). A swing slower than the
# record reached ~1 there and lost 0.1–0.3 by chance: it was refused in 9 of 15 cases of
# a 20 s swing; where neither half can decide, the in-sample tests decide alone.
CV_MIN_REACH = 16.0
WHITE_ALPHA = 1e-3  # a 60 s record has 6000 blocks: a small misfit of the noise model must not read as a cause

ALL_EFFECTS: tuple = SIGNAL_EFFECTS + SIDE_EFFECTS


# fitted like the effects, never named: measured properties of the setup
SETUP_PROPERTIES: tuple[str, ...] = tuple(e.name for e in ALL_EFFECTS if getattr(e, "setup_only", False))


def list_effects() -> list[tuple[str, str]]:
    """The effects a diagnosis may name (the setup's own properties are not among them)."""
    return [(e.name, e.summary) for e in ALL_EFFECTS if e.name not in SETUP_PROPERTIES]


@dataclass
class EffectResult:
    name: str
    kind: str  # "signal" or "side"
    params: dict[str, tuple[float, float]]
    p_value: float
    delta_bic: float
    gain: dict
    detail: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind,
                "params": {k: [v, s] for k, (v, s) in self.params.items()},
                "p_value": self.p_value, "delta_bic": self.delta_bic, "gain": self.gain, "detail": self.detail}


@dataclass
class Candidate:
    name: str
    status: str  # accepted / rejected / not applicable
    delta_bic: float = float("nan")
    p_value: float = float("nan")
    reason: str = ""


@dataclass
class DiagnosisResult:
    reference: str | None
    n_samples: int
    duration_s: float
    baseline: dict[str, tuple[float, float]]
    noise_model: dict[str, float]
    effects: list[EffectResult]
    candidates: list[Candidate]
    whiteness_p_before: float
    whiteness_p_after: float
    residual_rms_before: float
    residual_rms_after: float
    screening: dict
    cannot: list[str]
    compare_block: int = 1  # model and measurement compared as means over this many samples
    setup: list[dict] = field(default_factory=list)  # measured properties of the setup (nuisance values)
    negligible: list[dict] = field(default_factory=list)  # significant, but too small to matter
    not_physical: list[dict] = field(default_factory=list)  # a shape that fits, with impossible values
    # what the clocks are like (timestamps.HostClock), checked before the analysis
    timestamps: dict = field(default_factory=dict)
    # computations that failed, each in isolation: {"what": ..., "error": ...}; the rest stands
    failures: list[dict] = field(default_factory=list)
    # for plots and the report (not in the JSON)
    t_s: np.ndarray = field(repr=False, default=None)
    residual_before: np.ndarray = field(repr=False, default=None)
    residual_after: np.ndarray = field(repr=False, default=None)
    distance: dict = field(repr=False, default_factory=dict)

    @property
    def residual_white(self) -> bool:
        return bool(self.whiteness_p_after > WHITE_ALPHA)

    @property
    def unexplained(self) -> bool:
        return not self.residual_white

    def to_dict(self) -> dict:
        return {
            "effects": [e.to_dict() for e in self.effects],
            "residual_white": self.residual_white,
            "unexplained": self.unexplained,
            "reference": self.reference,
            "samples": self.n_samples,
            "duration_s": self.duration_s,
            "baseline": {k: [v, s] for k, (v, s) in self.baseline.items()},
            "noise_model": self.noise_model,
            "whiteness_p": {"before": self.whiteness_p_before, "after": self.whiteness_p_after},
            "residual_rms_mps2": {"before": self.residual_rms_before, "after": self.residual_rms_after},
            "candidates": [c.__dict__ for c in self.candidates],
            "screening": self.screening,
            "cannot_analyse": self.cannot,
            "compare_block_samples": self.compare_block,
            "setup": self.setup,
            "negligible": self.negligible,
            "not_physical": self.not_physical,
            "timestamps": self.timestamps,
            "failures": self.failures,
        }


def _prepare_with_estimate(data: DiagnosisInput, plan: EstimatePlan) -> Prepared:
    """Without a recorded reference the smoothed estimate stands in for it."""
    prep = prepare(data)
    if data.reference == "estimated":
        track = plan.run(data.t_s, data.acc_mps2, data.valid, data.lost_before)
        data.ref_pos_m, data.ref_vel_mps = track.pos_m, track.vel_mps
        prep.set_received_reading(np.nan_to_num(track.acc_mps2))
        prep.rest = track.standstill.astype(bool) & data.valid
    return prep


def diagnose(data: DiagnosisInput, settings: EstimatorSettings, returns_to_start: bool = False,
             progress: Callable[[str], None] = lambda msg: None) -> DiagnosisResult:
    period_s = check_sample_clock(data.t_s, data.lost_before)  # TimestampError (a ValueError): bad input
    host = check_host_clock(data.t_host_s, period_s) if data.t_host_s is not None else None
    plan = EstimatePlan(settings, returns_to_start)
    cannot: list[str] = []
    failures: list[dict] = []
    if data.reference is None:
        data.reference = "estimated"
    prep = _prepare_with_estimate(data, plan)
    progress("baseline: offset, drift, noise model")
    base = fit_model(prep, ())
    if prep.rest.sum() >= 64:
        prep.noise = fit_noise_model(prep.noise_series(base.residual))
    else:
        cannot.append("no rest long enough for the noise model: the residual is taken as white")
    base = fit_model(prep, ())
    p_white_before = _whiteness(prep, base)

    candidates: dict[str, Candidate] = {}
    usable: list[SignalEffect] = []
    for e in SIGNAL_EFFECTS:
        why = e.unusable(prep)
        if why:
            candidates[e.name] = Candidate(e.name, "not applicable", reason=why)
        else:
            usable.append(e)

    current, accepted = base, []
    start: dict[str, np.ndarray] = {}
    not_physical: list[dict] = []
    failed_cv: list[SignalEffect] = []
    # whiteness does not end the search: a Ljung–Box test on lags is weak against an effect
    # tied to a regressor (a 1 % scale error leaves the residual almost white); the rounds
    # go on until nothing passes the BIC margin, the test and the cross-validation, and
    # whiteness gives the verdict
    while usable:
        trials = []
        for e in usable:
            progress(f"round {len(accepted) + 1}: trying {e.name}")
            sig = _current_signal(prep, current)
            init = e.initial(prep, np.nan_to_num(current.residual), sig)
            fit = fit_model(prep, tuple(accepted) + (e,), {**start, e.name: init}, base_start=current.theta[:2])
            trials.append((fit.bic - current.bic, e, fit))
        trials.sort(key=lambda row: row[0])
        alpha = ALPHA / len(trials)
        chosen = None
        for dbic, e, fit in trials:
            k = fit.n_params - current.n_params
            p = float(chi2.sf(max(0.0, 2.0 * (fit.loglik - current.loglik)), k))
            candidates[e.name] = Candidate(e.name, "rejected", dbic, p, "ΔBIC or p not enough")
            if chosen is not None or not (dbic <= -BIC_MARGIN and p < alpha):
                continue
            theta = fit.effect_theta(e)[0]
            # a fit whose parameters no such effect can have: something of this shape,
            # but not this; it leaves the search (the report says so)
            why = getattr(e, "implausible", lambda prep, theta: None)(prep, theta) or physical(e.name, prep, theta)
            if why:
                candidates[e.name] = Candidate(e.name, "not physical", dbic, p, why)
                not_physical.append({"shape": e.name, "why": why, "delta_bic": dbic,
                                     "params": e.report(theta, fit.effect_theta(e)[1])})
                usable.remove(e)
                continue
            progress(f"round {len(accepted) + 1}: cross-validating {e.name}")
            cv = out_of_sample_gain(prep, tuple(accepted) + (e,), tuple(accepted),
                                    {**start, e.name: theta}, current.theta[:2])
            decided = [g for g, reach in cv if reach >= CV_MIN_REACH]
            folds = ", ".join(f"{g:.1f} at reach {reach:.3g}" for g, reach in cv) or "n/a"
            if not cv or (decided and min(decided) <= CV_MIN_GAIN):
                candidates[e.name] = Candidate(e.name, "rejected", dbic, p,
                                               f"fitted on one half, it does not predict the other "
                                               f"(log-likelihood gain {folds})")
                usable.remove(e)
                failed_cv.append(e)
                continue
            # said beside an accepted effect when no half could judge it (the report shows it)
            note = "" if decided else (f"cross-validation could not judge (gain {folds}; a half decides from "
                                       f"reach {CV_MIN_REACH:g}): decided in-sample")
            chosen = (dbic, e, fit, p, note)
        if chosen is None:
            break
        dbic, best, fit, p, note = chosen
        candidates[best.name] = Candidate(best.name, "accepted", dbic, p, note)
        accepted.append(best)
        usable.remove(best)
        # a candidate whose cross-validation failed was judged against a model that lacked
        # what has just been accepted (the part's own sensitivity, say, which a half fitted
        # without it reads into the candidate): it is tried again against the new model
        usable.extend(failed_cv)
        failed_cv.clear()
        for e in accepted:
            start[e.name] = fit.effect_theta(e)[0]
        current = fit
        # the rests were seen through the effect (a tilt shifts each end's level): the
        # noise model is refitted on the new residual, and the next round compares on it
        if prep.rest.sum() >= 64:
            prep.noise = fit_noise_model(prep.noise_series(current.residual))
            current = fit_model(prep, tuple(accepted), dict(start), base_start=current.theta[:2])

    # backward: each accepted effect must still pay for itself once the others are in
    changed = True
    while changed and len(accepted) > 1:
        changed = False
        for e in list(accepted):
            rest = [x for x in accepted if x is not e]
            progress(f"backward pass: without {e.name}")
            without = fit_model(prep, tuple(rest), {x.name: start[x.name] for x in rest},
                                base_start=current.theta[:2])
            if without.bic - current.bic < BIC_MARGIN:
                candidates[e.name] = Candidate(e.name, "rejected", current.bic - without.bic, float("nan"),
                                               "not needed once the others are in (backward pass)")
                accepted = rest
                current = without
                for x in accepted:
                    start[x.name] = current.effect_theta(x)[0]
                changed = True
                break

    # the gains, in order of acceptance, each against the model without it — all under
    # the final noise model (log-likelihoods under different noise models do not compare)
    history = []
    for i, e in enumerate(accepted):
        before = fit_model(prep, tuple(accepted[:i]), {x.name: start[x.name] for x in accepted[:i]},
                           base_start=current.theta[:2])
        after = current if i == len(accepted) - 1 else fit_model(
            prep, tuple(accepted[:i + 1]), {x.name: start[x.name] for x in accepted[:i + 1]},
            base_start=current.theta[:2])
        history.append((e, before, after))

    effects: list[EffectResult] = []
    setup: list[dict] = []
    negligible: list[dict] = []
    before_plan = plan.baseline(data)
    for e, before, after in history:
        # the parameters as the final model has them, every accepted effect in (what the
        # backward pass judged): an effect accepted early, fitted before a later one (the
        # part's own output filter, say), reads part of it as its own — a part at −0.96 %
        # read as −1.04 % before the filter was in, and was named outside its tolerance
        theta, std = current.effect_theta(e)
        progress(f"gain of {e.name}: distance estimate before and after")
        step_plan = _isolated(f"the compensation of {e.name}", failures,
                              lambda: before_plan.with_signal(prep, after, accepted[: accepted.index(e) + 1]))
        if isinstance(step_plan, dict):  # failed: no distance for it, the chain goes on without it
            distance, step_plan = step_plan, before_plan
        else:
            distance = _isolated(f"distance gain of {e.name}", failures,
                                 lambda: distance_gain(prep, before_plan, step_plan))
        gain = {
            "residual_rms_mps2": [before.residual_rms, after.residual_rms],
            "loglik": [before.loglik, after.loglik],
            "distance": distance,
        }
        before_plan = step_plan
        result = EffectResult(e.name, "signal", e.report(theta, std), candidates[e.name].p_value,
                              candidates[e.name].delta_bic, gain)
        _classify(result, setup_range(e.name, prep, theta, std), effects, setup, negligible, candidates)

    for s in SIDE_EFFECTS:
        why = s.unusable(prep)
        if why:
            candidates[s.name] = Candidate(s.name, "not applicable", reason=why)
            continue
        progress(f"testing {s.name}")
        test = _isolated(f"the {s.name} test", failures, lambda: s.test(prep, current.residual))
        if isinstance(test, dict):  # it failed: said in failures, the rest of the report stands
            candidates[s.name] = Candidate(s.name, "failed", reason=test["why"])
            continue
        dbic = -2.0 * (test.loglik_after - test.loglik_before) + test.extra_params * math.log(max(current.n, 2))
        ok = test.significant(ALPHA / len(SIDE_EFFECTS)) and dbic <= -BIC_MARGIN
        # a test that could not be made (no parameters fitted) says why in its detail
        candidates[s.name] = Candidate(s.name, "accepted" if ok else "rejected", dbic, test.p_value,
                                       "" if ok else (test.detail if not test.params else "ΔBIC or p not enough"))
        if ok:
            progress(f"gain of {s.name}: distance estimate before and after")
            no_estimate = host.why_no_estimate() if host is not None and test.values.get("host_time") else None
            if no_estimate:
                without = step_plan = None
            elif test.values.get("host_time"):
                # the baseline trusts host times as the board's; the extension knows better
                without, step_plan = before_plan.as_host_timed(prep), before_plan
            elif test.values.get("lost"):
                without, step_plan = before_plan.as_gapless(prep), before_plan
            else:
                without, step_plan = before_plan, before_plan.with_side(prep, s, test)
            gain = {"loglik": [test.loglik_before, test.loglik_after],
                    "distance": {"available": False, "why": no_estimate} if no_estimate else _isolated(
                        f"distance gain of {s.name}", failures, lambda: distance_gain(prep, without, step_plan))}
            if test.rms_unit is not None:  # the same key shape as a signal effect's residual_rms_mps2
                gain[f"residual_rms_{test.rms_unit}"] = [test.rms_before, test.rms_after]
            if test.position_mm is not None:
                gain["position_mm"] = test.position_mm
            result = EffectResult(s.name, "side", test.params, test.p_value, dbic, gain, test.detail)
            # judged like a signal effect's parameters, where the test gives them
            in_setup = setup_range(s.name, prep, test.theta) if test.theta is not None else None
            why = physical(s.name, prep, test.theta) if test.theta is not None else None
            if why and not in_setup:
                candidates[s.name] = Candidate(s.name, "not physical", dbic, test.p_value, why)
                not_physical.append({"shape": s.name, "why": why, "delta_bic": dbic, "params": test.params})
                continue
            if _classify(result, in_setup, effects, setup, negligible, candidates) and step_plan is not None:
                before_plan = step_plan

    regs = candidate_regressors(prep, prep.reading_mps2, data.ref_pos_m)
    screening = {
        when: {"correlations": _isolated(f"correlations {when}", failures,
                                         lambda: correlations(prep, fit.residual, regs), []),
               "spectrum_peaks": _isolated(f"spectrum peaks {when}", failures,
                                           lambda: spectrum_peaks(prep, fit.whitened), []),
               "allan": _isolated(f"Allan slopes {when}", failures, lambda: allan_slopes(prep, fit.residual), [])}
        for when, fit in (("before", base), ("after", current))
    }
    if data.reference == "estimated":
        cannot.append("no recorded reference: the smoothed estimate stands in for it, so effects that "
                      "change the motion's reading (scale, nonlinearity, filters, delay) cannot be seen")
    order = [e.name for e in ALL_EFFECTS]
    return DiagnosisResult(
        reference=data.reference,
        n_samples=len(data),
        duration_s=data.duration_s,
        baseline=base.baseline_params(),
        noise_model={"ar": prep.noise.ar, "ma": prep.noise.ma, "lag1": prep.noise.lag1},
        effects=effects,
        candidates=sorted(candidates.values(), key=lambda c: order.index(c.name)),
        whiteness_p_before=p_white_before,
        whiteness_p_after=_whiteness(prep, current),
        residual_rms_before=base.residual_rms,
        residual_rms_after=current.residual_rms,
        screening=screening,
        cannot=cannot,
        compare_block=prep.block,
        setup=setup,
        negligible=negligible,
        not_physical=not_physical,
        t_s=data.t_s,
        residual_before=base.residual,
        residual_after=current.residual,
        distance={"before": _isolated("the baseline's track", failures, lambda: plan.baseline(data).track(prep), None),
                  "after": _isolated("the extended model's track", failures, lambda: before_plan.track(prep), None)},
        timestamps={"sample_period_s": period_s, "host": host.to_dict() if host is not None else None},
        failures=failures,
    )


def _isolated(what: str, failures: list[dict], compute: Callable, fallback=None):
    """One computation of the report, in isolation: what it returns, or — when it fails
    (a bug, or an input no check foresaw) — `fallback` (default: a distance result that
    says why it is not available), the failure recorded in `failures`, and the rest of
    the report standing. A failure is never silent: the JSON and the text list it."""
    try:
        return compute()
    except Exception as err:  # noqa: BLE001 — isolation is the point; recorded below
        why = f"{what} failed: {type(err).__name__}: {err}"
        failures.append({"what": what, "error": f"{type(err).__name__}: {err}"})
        return {"available": False, "why": why} if fallback is None else fallback


def _classify(result: EffectResult, setup_why: str | None, effects: list, setup: list, negligible: list,
              candidates: dict) -> bool:
    """Put an accepted effect where it belongs: the setup's own properties, the named
    effects, or the negligible ones. True when it is named."""
    gain = result.gain
    dist = gain.get("distance", {})
    distance_mm = float(dist["improvement_mm"]) if dist.get("available") else None
    rms = next((gain[k] for k in gain if k.startswith("residual_rms")), None)
    position_mm = gain.get("position_mm")
    # an effect sized by the position it makes elsewhere (host timestamps) has a residual
    # whose share says nothing (side_effects.host_time_position_mm): judged by that instead
    share = residual_share(*rms) if rms is not None and position_mm is None else None
    size = {"residual_share": share, "distance_improvement_mm": distance_mm}
    if position_mm is not None:
        size["position_mm"] = position_mm
    if setup_why:
        setup.append({"name": result.name, "params": result.params, "what": setup_why, **size})
        candidates[result.name].status = "setup"
        candidates[result.name].reason = setup_why
        return False
    if result.name == "sample_loss":  # counted, not fitted: a gap is a fact
        effects.append(result)
        return True
    chance = distance_mm is not None and distance_mm < 0 and distance_loss_is_chance(dist)
    if chance:  # said in the report and the JSON beside the loss
        dist["loss_within_chance"] = True
    named, why = matters(share, distance_mm, position_mm, loss_is_chance=chance)
    if named:
        effects.append(result)
        return True
    negligible.append({"name": result.name, "params": result.params, "why": why, **size})
    candidates[result.name].status = "negligible"
    candidates[result.name].reason = why
    return False


def _whiteness(prep: Prepared, fit: ModelFit) -> float:
    """Block Ljung–Box p of the whitened residual. Against the smoothed estimate only the
    standstills count: in motion the estimate follows the reading, so the residual there
    is smooth by construction and says nothing about whiteness."""
    if prep.data.reference != "estimated":
        return block_whiteness_p(prep, fit.whitened)
    still = prep.rest[prep.fit_mask]
    return block_whiteness_p(prep, fit.whitened[still]) if still.sum() >= 50 else float("nan")


def _current_signal(prep: Prepared, fit: ModelFit) -> Signal:
    """The motion's reading with the accepted filters and delay applied (what new effects act on)."""
    from gateway.core.diagnosis.model_fit import BASELINE_PARAMS

    sig = Signal(prep.reading_full.copy(), prep.where, None if prep.data.ref_pos_m is None else prep.data.ref_pos_m.copy())
    i = len(BASELINE_PARAMS)
    for e in fit.effects:
        k = len(e.param_names)
        if e.stage < 2:
            e.apply(prep, fit.theta[i:i + k], sig)
        i += k
    return sig
