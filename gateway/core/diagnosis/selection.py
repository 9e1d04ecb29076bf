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

from collections.abc import Callable
from dataclasses import replace

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
from gateway.core.diagnosis.gain import EstimatePlan
from gateway.core.diagnosis.identifiability import (
    REFERENCE_PATH_EFFECT,
    alternatives,
    one_cause_for_the_reference_path,
    temperature_in_line_with_drift,
    what_separates,
)
from gateway.core.diagnosis.judgement import physical
from gateway.core.diagnosis.model_fit import ModelFit, current_signal, cv_gain_of, fit_model
from gateway.core.diagnosis.placement import Placement, _place_side_effects, _place_signal_effects
from gateway.core.diagnosis.reading import fit_noise_model
from gateway.core.diagnosis.results import WHITE_ALPHA, Candidate, DiagnosisResult, EffectResult, _isolated
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
from gateway.core.diagnosis.signal_effects import SIGNAL_EFFECTS
from gateway.core.diagnosis.signal_interface import SignalEffect
from gateway.core.diagnosis.timestamps import check_host_clock, check_sample_clock
from gateway.core.estimator_settings import EstimatorSettings

# the records of the report live in results.py; named here too, as before the split
__all__ = ["ALL_EFFECTS", "SETUP_PROPERTIES", "WHITE_ALPHA", "Candidate", "DiagnosisResult", "EffectResult",
           "diagnose", "leftover_structure", "list_effects"]

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
    # The estimator's reported σ carries the calibration's tolerance on the gain (per move:
    # docs/estimation.md, "Never confidently wrong"); the diagnosis measures the gain against
    # the reference instead (scale_factor, nonlinearity, cross-talk are its candidates), so the
    # σ it calls "known" (judgement.matters) leaves that prior out: a compensation that makes
    # the distance worse is not excused by the uncertainty it is there to resolve
    plan = EstimatePlan(replace(settings, sensitivity_std_frac=0.0), returns_to_start,
                        standstill_hint=data.standstill_hint)
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
    not_physical: list[dict] = []
    fitted: dict[str, dict] = {}  # each signal candidate's parameters as last fitted
    current, accepted, start, usable = _forward_selection(prep, base, candidates, not_physical, fitted, progress)
    current, accepted, redundant = _backward_pass(prep, current, accepted, start, candidates, progress)

    progress("identifiability: what else explains the same residual")
    twins = _isolated("identifiability", failures,
                      lambda: alternatives(prep, current, accepted, start, usable + redundant, ALPHA), {})
    slow = _isolated("temperature against drift", failures, lambda: temperature_in_line_with_drift(prep, ALPHA), None)
    if slow and "temperature_offset" in candidates and candidates["temperature_offset"].status != "accepted":
        candidates["temperature_offset"].not_separable_from = ["drift"]
        cannot.append(slow)

    history = _gain_history(prep, current, accepted, start)
    report = Placement(candidates, failures, not_physical)
    report.leftover = _isolated("leftover structure", failures,
                                lambda: leftover_structure(prep, current, ALPHA), None)
    before_plan = plan.baseline(data)
    before_plan = _place_signal_effects(prep, history, current, accepted, twins, before_plan, report, progress)
    before_plan = _place_side_effects(prep, current, host, before_plan, report, progress)
    effects, setup, negligible, leftover = report.effects, report.setup, report.negligible, report.leftover
    model_terms = report.model_terms

    for name in one_cause_for_the_reference_path(effects):
        path = next(e for e in effects if e.name == REFERENCE_PATH_EFFECT)
        candidates[path.name].not_separable_from = list(path.not_separable_from)
        candidates[name].status = "not separable"
        candidates[name].reason = (f"named as part of {path.name}: a low-pass reads the motion the same in the "
                                   "sensor and in the reference's path, and the reference has dynamics of its own "
                                   f"({what_separates(path.name, name)} would place it)")

    screening = _screening(prep, data, base, current, failures)
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



def _forward_selection(prep: Prepared, base: ModelFit, candidates: dict[str, Candidate], not_physical: list[dict],
                       fitted: dict[str, dict], progress: Callable[[str], None]) -> tuple:
    """The forward rounds: each usable signal effect tried jointly with those accepted, the
    first predictive and physical one accepted, until none is. Returns the final fit, the
    accepted effects in order, their fitted starts, and the effects still usable; fills
    `candidates`, `not_physical` (a shape that fits with values no part can have) and
    `fitted` (each candidate's parameters as last fitted: `--model-with` writes them) in
    place — the caller's containers, which the report reads."""
    usable: list[SignalEffect] = []
    for e in SIGNAL_EFFECTS:
        why = e.unusable(prep)
        if why:
            candidates[e.name] = Candidate(e.name, "not applicable", reason=why)
        else:
            usable.append(e)

    current, accepted = base, []
    start: dict[str, np.ndarray] = {}
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

    return current, accepted, start, usable


def _backward_pass(prep: Prepared, current: ModelFit, accepted: list, start: dict[str, np.ndarray],
                   candidates: dict[str, Candidate], progress: Callable[[str], None]) -> tuple:
    """Drop any accepted effect the others make redundant. Returns the final fit, the
    effects kept, and those dropped (tried again for identifiability); `start` is updated."""
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
    return current, accepted, redundant


def _gain_history(prep: Prepared, current: ModelFit, accepted: list, start: dict[str, np.ndarray]) -> list:
    """Each accepted effect with the fits without and with it: (effect, before, after)."""
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
    return history


def _screening(prep: Prepared, data: DiagnosisInput, base: ModelFit, current: ModelFit,
               failures: list[dict]) -> dict:
    """Correlations, spectrum peaks and Allan slopes of the residual before and after."""
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
    return screening


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



def _whiteness(prep: Prepared, fit: ModelFit) -> float:
    """Block Ljung–Box p of the whitened residual. Against the smoothed estimate only the
    standstills count: in motion the estimate follows the reading, so the residual there
    is smooth by construction and says nothing about whiteness."""
    if prep.data.reference != "estimated":
        return block_whiteness_p(prep, fit.whitened)
    still = prep.rest[prep.fit_mask]
    return block_whiteness_p(prep, fit.whitened[still]) if still.sum() >= MIN_WHITENESS_SAMPLES else float("nan")
