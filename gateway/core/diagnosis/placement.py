"""The placement of the accepted effects: each one's gain measured (the distance estimate
before and after it), then put where it belongs — the setup's own property, a named
effect, a negligible one, or not physical (`_classify`). Signal effects in order of
acceptance, then the side effects, each tested once on its own data."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from gateway.core.diagnosis.context import Prepared
from gateway.core.diagnosis.criterion import ALPHA
from gateway.core.diagnosis.gain import EstimatePlan, distance_gain
from gateway.core.diagnosis.judgement import distance_interval, matters, physical, residual_share, setup_range
from gateway.core.diagnosis.model_fit import ModelFit
from gateway.core.diagnosis.results import Candidate, EffectResult, _isolated
from gateway.core.diagnosis.side_effects import SIDE_EFFECTS


@dataclass
class Placement:
    """The report's lists, filled as the effects are placed: the candidates by name, the
    failures, the largest leftover structure (what a small effect may be masked by), and
    where each accepted effect went."""
    candidates: dict[str, Candidate]
    failures: list[dict]
    not_physical: list[dict]
    leftover: dict | None = None
    effects: list[EffectResult] = field(default_factory=list)
    setup: list[dict] = field(default_factory=list)
    negligible: list[dict] = field(default_factory=list)
    model_terms: list[dict] = field(default_factory=list)


def _place_signal_effects(prep: Prepared, history: list, current: ModelFit, accepted: list, twins: dict,
                          before_plan: EstimatePlan, report: Placement,
                          progress: Callable[[str], None]) -> EstimatePlan:
    """Each accepted signal effect's gain, then its place; the plan with every named one in."""
    candidates, failures, leftover = report.candidates, report.failures, report.leftover
    effects, setup, negligible = report.effects, report.setup, report.negligible
    not_physical, model_terms = report.not_physical, report.model_terms
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
    return before_plan


def _place_side_effects(prep: Prepared, current: ModelFit, host, before_plan: EstimatePlan, report: Placement,
                        progress: Callable[[str], None]) -> EstimatePlan:
    """Each side effect tested once on its own data, judged, and placed; the plan with
    every named one in."""
    candidates, failures, leftover = report.candidates, report.failures, report.leftover
    effects, setup, negligible = report.effects, report.setup, report.negligible
    not_physical = report.not_physical
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
    return before_plan


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

