"""The diagnosis: baseline, look, add effects one at a time, judge, measure the gain.

Selection (signal effects on the measured axis), forward:
  1. fit the baseline (offset + drift) and the ARMA(1,1) noise model on the rests;
  2. fit every remaining candidate jointly with those already accepted, starting from
     its own quick fit on the current residual; order them by in-sample ΔBIC;
  3. accept the first that predicts the blocks it was not fitted on better than chance
     (criterion.py, at ALPHA split over the candidates of the round) and is physical;
     otherwise stop. A backward pass drops any the others make redundant (same test).
Then each accepted effect is placed (the setup's property, named, or not — judgement.py),
what else explains the same residual is found (identifiability.py), and the gain is
measured (gain.py). Side effects (other axis, host clock, seq gaps, bias wander) are each
fitted once on their own data and judged by the same out-of-block criterion. "Unexplained" is set when the final
residual is still not white: structure remains that no candidate explains.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2, norm

from gateway.core.diagnosis.context import (
    MIN_NOISE_POINTS,
    USABLE_COLUMN_FRACTION,
    DiagnosisInput,
    Prepared,
    prepare,
)
from gateway.core.diagnosis.criterion import ALPHA
from gateway.core.diagnosis.gain import EstimatePlan, distance_gain
from gateway.core.diagnosis.identifiability import (
    REFERENCE_PATH_EFFECT,
    alternatives,
    one_cause_for_the_reference_path,
    temperature_in_line_with_drift,
    what_separates,
)
from gateway.core.diagnosis.judgement import (
    distance_interval,
    matters,
    physical,
    residual_share,
    setup_range,
)
from gateway.core.diagnosis.model_fit import ModelFit, current_signal, cv_gain_of, fit_model
from gateway.core.diagnosis.reading import fit_noise_model
from gateway.core.diagnosis.screening import (
    WHITENESS_BLOCK_S,
    allan_slopes,
    block_whiteness_p,
    candidate_regressors,
    correlations,
    spectrum_line,
    spectrum_peaks,
)
from gateway.core.diagnosis.side_effects import SIDE_EFFECTS
from gateway.core.diagnosis.signal_effects import SIGNAL_EFFECTS, SignalEffect
from gateway.core.diagnosis.timestamps import check_host_clock, check_sample_clock
from gateway.core.estimator_settings import EstimatorSettings

WHITE_ALPHA = 1e-3  # a 60 s record has 6000 blocks: a small misfit of the noise model must not read as a cause
# without a reference only the rests are judged for whiteness: 50 samples at rest make the
# 10 block means of WHITENESS_BLOCK_S (at 500 samples/s) that a Ljung–Box test needs at
# the least (drift_fit.ljung_box: h = n/5 lags, one at n = 5, and its χ² law wants more)
MIN_WHITENESS_SAMPLES = 50

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
    # the causes that explain the same residual on this record as well (identifiability.py)
    not_separable_from: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind,
                "params": {k: [v, s] for k, (v, s) in self.params.items()},
                "p_value": self.p_value, "delta_bic": self.delta_bic, "gain": self.gain, "detail": self.detail,
                "not_separable_from": list(self.not_separable_from)}


@dataclass
class Candidate:
    name: str
    status: str  # accepted / rejected / not applicable
    delta_bic: float = float("nan")
    p_value: float = float("nan")
    reason: str = ""
    # a signal effect's parameters as last fitted (SI units, model_compensation's names),
    # named or not: what `diagnose --model-out --model-with NAME` writes for it
    model_params: dict = field(default_factory=dict)
    # the causes that explain the same residual on this record (named effects only)
    not_separable_from: list = field(default_factory=list)


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
    # the largest structure left in the final residual (leftover_structure), None: none
    leftover: dict | None = None
    # what the clocks are like (timestamps.HostClock), checked before the analysis
    timestamps: dict = field(default_factory=dict)
    # computations that failed, each in isolation: {"what": ..., "error": ...}; the rest stands
    failures: list[dict] = field(default_factory=list)
    # the extended model: the signal effects named or kept as the setup's, in order of
    # acceptance, parameters in SI units (`diagnose --model-out`, model_compensation)
    model_terms: list[dict] = field(default_factory=list)
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
            "leftover": self.leftover,
            "failures": self.failures,
            "model_terms": self.model_terms,
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
    if prep.rest.sum() >= MIN_NOISE_POINTS:
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
    fitted: dict[str, dict] = {}  # each signal candidate's parameters as last fitted
    # whiteness does not end the search: a Ljung–Box test on lags is weak against an effect
    # tied to a regressor (a 1 % scale error leaves the residual almost white); the rounds
    # go on until no candidate predicts the blocks it was not fitted on (criterion.py),
    # and whiteness gives the verdict
    while usable:
        trials = []
        for e in usable:
            progress(f"round {len(accepted) + 1}: trying {e.name}")
            sig = current_signal(prep, current)
            init = e.initial(prep, np.nan_to_num(current.residual), sig)
            fit = fit_model(prep, tuple(accepted) + (e,), {**start, e.name: init}, base_start=current.theta[:2])
            trials.append((fit.bic - current.bic, e, fit))
        # in-sample ΔBIC only orders the candidates; each is judged by the one criterion
        trials.sort(key=lambda row: row[0])
        alpha = ALPHA / len(trials)
        chosen = None
        for dbic, e, fit in trials:
            k = fit.n_params - current.n_params
            p = float(chi2.sf(max(0.0, 2.0 * (fit.loglik - current.loglik)), k))
            fitted[e.name] = e.model_params(prep, fit.effect_theta(e)[0])
            if chosen is not None:
                candidates[e.name] = Candidate(e.name, "rejected", dbic, p, "another was chosen this round")
                continue
            cv = cv_gain_of(prep, fit, current)
            if not cv.predictive(alpha, k):
                candidates[e.name] = Candidate(e.name, "rejected", dbic, p,
                                               f"not predictive: {cv.text()} (needs > "
                                               f"{cv.threshold(alpha, k):.1f}: α = {alpha:.1g})")
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
            chosen = (dbic, e, fit, p, cv.text())
        if chosen is None:
            break
        dbic, best, fit, p, note = chosen
        candidates[best.name] = Candidate(best.name, "accepted", dbic, p, note)
        accepted.append(best)
        usable.remove(best)
        for e in accepted:
            start[e.name] = fit.effect_theta(e)[0]
        current = fit
        # the rests were seen through the effect (a tilt shifts each end's level): the
        # noise model is refitted on the new residual, and the next round compares on it
        if prep.rest.sum() >= MIN_NOISE_POINTS:
            prep.noise = fit_noise_model(prep.noise_series(current.residual))
            current = fit_model(prep, tuple(accepted), dict(start), base_start=current.theta[:2])

    # backward: each accepted effect must still pay for itself once the others are in
    changed = True
    redundant: list[SignalEffect] = []  # dropped by the backward pass: tried again for identifiability
    while changed and len(accepted) > 1:
        changed = False
        for e in list(accepted):
            rest = [x for x in accepted if x is not e]
            progress(f"backward pass: without {e.name}")
            without = fit_model(prep, tuple(rest), {x.name: start[x.name] for x in rest},
                                base_start=current.theta[:2])
            cv = cv_gain_of(prep, current, without)
            if not cv.predictive(ALPHA / len(accepted), len(e.param_names)):
                candidates[e.name] = Candidate(e.name, "rejected", current.bic - without.bic, float("nan"),
                                               f"not needed once the others are in (backward pass: {cv.text()})")
                accepted = rest
                redundant.append(e)
                current = without
                for x in accepted:
                    start[x.name] = current.effect_theta(x)[0]
                changed = True
                break

    progress("identifiability: what else explains the same residual")
    twins = _isolated("identifiability", failures,
                      lambda: alternatives(prep, current, accepted, start, usable + redundant, ALPHA), {})
    slow = _isolated("temperature against drift", failures, lambda: temperature_in_line_with_drift(prep, ALPHA), None)
    if slow and "temperature_offset" in candidates and candidates["temperature_offset"].status != "accepted":
        candidates["temperature_offset"].not_separable_from = ["drift"]
        cannot.append(slow)

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
    leftover = _isolated("leftover structure", failures, lambda: leftover_structure(prep, current, ALPHA), None)
    before_plan = plan.baseline(data)
    model_terms: list[dict] = []
    for e, before, after in history:
        # the parameters as the final model has them, every accepted effect in (what the
        # backward pass judged): an effect accepted early, fitted before a later one (the
        # part's own output filter, say), reads part of it as its own — a part at −0.96 %
        # read as −1.04 % before the filter was in, and was named outside its tolerance
        theta, std = current.effect_theta(e)
        progress(f"gain of {e.name}: distance estimate before and after")
        step_plan = _isolated(f"the compensation of {e.name}", failures,
                              lambda bp=before_plan, a=after, e=e:
                              bp.with_signal(prep, a, accepted[: accepted.index(e) + 1]))
        if isinstance(step_plan, dict):  # failed: no distance for it, the chain goes on without it
            distance, step_plan = step_plan, before_plan
        else:
            distance = _isolated(f"distance gain of {e.name}", failures,
                                 lambda bp=before_plan, sp=step_plan: distance_gain(prep, bp, sp))
        gain = {
            "residual_rms_mps2": [before.residual_rms, after.residual_rms],
            "loglik": [before.loglik, after.loglik],
            "distance": distance,
        }
        before_plan = step_plan
        result = EffectResult(e.name, "signal", e.report(theta, std), candidates[e.name].p_value,
                              candidates[e.name].delta_bic, gain, not_separable_from=twins.get(e.name, []))
        candidates[e.name].not_separable_from = list(result.not_separable_from)
        in_setup = setup_range(e.name, prep, theta, std)
        # the range is checked on the parameters named, the final model's: a value
        # physical when the effect was accepted may have moved out once later effects
        # and the refitted noise model came in (a damping ratio drifting past 0.5)
        why = None if in_setup else (getattr(e, "implausible", lambda p, t: None)(prep, theta)
                                     or physical(e.name, prep, theta))
        if why:
            candidates[e.name].status, candidates[e.name].reason = "not physical", f"in the final model: {why}"
            not_physical.append({"shape": e.name, "why": why, "delta_bic": candidates[e.name].delta_bic,
                                 "params": result.params})
            continue
        if _classify(result, in_setup, effects, setup, negligible, candidates, leftover) or in_setup:
            model_terms.append({"name": e.name, "params": e.model_params(prep, theta)})

    for s in SIDE_EFFECTS:
        why = s.unusable(prep)
        if why:
            candidates[s.name] = Candidate(s.name, "not applicable", reason=why)
            continue
        progress(f"testing {s.name}")
        test = _isolated(f"the {s.name} test", failures, lambda s=s: s.test(prep, current.residual))
        if isinstance(test, dict):  # it failed: said in failures, the rest of the report stands
            candidates[s.name] = Candidate(s.name, "failed", reason=test["why"])
            continue
        dbic = -2.0 * (test.loglik_after - test.loglik_before) + test.extra_params * math.log(max(current.n, 2))
        # the one criterion (criterion.py), at the false-alarm rate split over the side tests
        alpha = ALPHA / len(SIDE_EFFECTS)
        ok = test.predictive(alpha)
        # a test that could not be made (no parameters fitted) says why in its detail
        why_not = test.detail if not test.params else (
            f"not predictive: {test.cv.text()} (needs > {test.cv.threshold(alpha, test.extra_params):.1f}: "
            f"α = {alpha:.1g})" if test.cv is not None else "no out-of-block test")
        candidates[s.name] = Candidate(s.name, "accepted" if ok else "rejected", dbic, test.p_value,
                                       test.cv.text() if ok else why_not)
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
                        f"distance gain of {s.name}", failures,
                        lambda w=without, sp=step_plan: distance_gain(prep, w, sp))}
            if test.rms_unit is not None:  # the same key shape as a signal effect's residual_rms_mps2
                gain[f"residual_rms_{test.rms_unit}"] = [test.rms_before, test.rms_after]
            if test.position_mm is not None:
                gain["position_mm"] = test.position_mm
            if "host_scatter_periods" in test.values:
                gain["host_scatter_periods"] = test.values["host_scatter_periods"]
            result = EffectResult(s.name, "side", test.params, test.p_value, dbic, gain, test.detail)
            # judged like a signal effect's parameters, where the test gives them
            in_setup = setup_range(s.name, prep, test.theta) if test.theta is not None else None
            why = physical(s.name, prep, test.theta) if test.theta is not None else None
            if why and not in_setup:
                candidates[s.name] = Candidate(s.name, "not physical", dbic, test.p_value, why)
                not_physical.append({"shape": s.name, "why": why, "delta_bic": dbic, "params": test.params})
                continue
            if _classify(result, in_setup, effects, setup, negligible, candidates, leftover) and step_plan is not None:
                before_plan = step_plan

    for name in one_cause_for_the_reference_path(effects):
        path = next(e for e in effects if e.name == REFERENCE_PATH_EFFECT)
        candidates[path.name].not_separable_from = list(path.not_separable_from)
        candidates[name].status = "not separable"
        candidates[name].reason = (f"named as part of {path.name}: a low-pass reads the motion the same in the "
                                   "sensor and in the reference's path, and the reference has dynamics of its own "
                                   f"({what_separates(path.name, name)} would place it)")

    regs = candidate_regressors(prep, prep.reading_mps2, data.ref_pos_m)
    screening = {
        when: {"correlations": _isolated(f"correlations {when}", failures,
                                         lambda fit=fit: correlations(prep, fit.residual, regs), []),
               "spectrum_peaks": _isolated(f"spectrum peaks {when}", failures,
                                           lambda fit=fit: spectrum_peaks(prep, fit.whitened), []),
               "allan": _isolated(f"Allan slopes {when}", failures,
                                  lambda fit=fit: allan_slopes(prep, fit.residual), [])}
        for when, fit in (("before", base), ("after", current))
    }
    if data.reference == "estimated":
        cannot.append("no recorded reference: the smoothed estimate stands in for it, so effects that "
                      "change the motion's reading (scale, nonlinearity, filters, delay) cannot be seen")
    for name, params in fitted.items():
        if name in candidates:
            candidates[name].model_params = params
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
        leftover=leftover,
        timestamps={"sample_period_s": period_s, "host": host.to_dict() if host is not None else None},
        failures=failures,
        model_terms=model_terms,
    )


def leftover_structure(prep: Prepared, fit: ModelFit, alpha: float) -> dict | None:
    """The largest structure the final residual still has, with its share of the residual
    variance: a correlation with the other axis (significant at alpha), or a spectral line
    of the whitened residual above what white noise reaches at alpha over all the
    spectrum's bins (a Welch estimate of K segments is the level × χ²₂ₖ/2K). None: none."""
    found = []
    other = prep.data.other_mps2
    if other is not None and np.isfinite(other).mean() > USABLE_COLUMN_FRACTION:
        # on WHITENESS_BLOCK_S means, as whiteness is judged: both axes are divided by the
        # same T2 count and share its rounding (the baseline's own, at the sample rate)
        b = max(1, int(round(WHITENESS_BLOCK_S / prep.compare_period_s)))
        m = prep.fit_mask
        x = prep.whiten_masked(np.nan_to_num(fit.residual), m)
        y = prep.whiten_masked(np.nan_to_num(other - np.nanmean(other)), m)
        n = x.size // b * b
        x, y = x[:n].reshape(-1, b).mean(axis=1), y[:n].reshape(-1, b).mean(axis=1)
        if x.size > 3 and np.std(x) > 0 and np.std(y) > 0:
            r = float(np.corrcoef(x, y)[0, 1])
            if 2.0 * norm.sf(abs(r) * np.sqrt(x.size)) < alpha:
                found.append({"what": f"correlation r = {r:+.2f} with the other axis", "share": r * r})
    line = spectrum_line(prep, fit.whitened, alpha)
    if line is not None:
        found.append(line)
    return max(found, key=lambda row: row["share"]) if found else None


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
              candidates: dict, leftover: dict | None = None) -> bool:
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
    interval = distance_interval(dist)
    if interval is not None:  # said in the report and the JSON beside the gain
        dist["interval_mm"] = list(interval)
    scatter = gain.get("host_scatter_periods")
    masked = None
    if leftover and share is not None and share < leftover["share"]:
        masked = f"{leftover['what']}: {100 * leftover['share']:.1f} % of the residual variance"
    named, why = matters(dist, scatter, masked)
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
    return block_whiteness_p(prep, fit.whitened[still]) if still.sum() >= MIN_WHITENESS_SAMPLES else float("nan")
