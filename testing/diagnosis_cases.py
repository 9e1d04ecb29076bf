"""Measured-like recordings with hidden effects, for the diagnosis tests and benchmark.

One place builds every case, so the tests (tests/diagnosis/test_diagnosis.py) and the benchmark
(benchmarks/accuracy/diagnosis_benchmark.py) judge the diagnosis the same way:

    terms, data = make_case(("scale_factor",), seed)   # the effect is chosen here...
    result = run_diagnosis(data)                        # ...and diagnose is never told
    outcome = judge(("scale_factor",), terms, data, result)

A case is the paper's reciprocating motion (4 strokes of 30 cm, ~7.6 s at 500 samples/s)
— or, for bias_random_walk, a 60 s standstill (sensor_effects.SCENARIO_FOR: a walk is a
standstill phenomenon and 7.6 s cannot tell it from offset and drift) — simulated by the baseline simulator with
the chosen error terms of
gateway.core.sensor_effects, parameters drawn by ``draw_effect`` at the documented sizes
(``EFFECT_SIZES``) from ``numpy.random.default_rng([seed, 7])``, in the order given;
the simulator's own noise is seeded with ``seed``. The board's raw recording is then
read back exactly as ``adxlgw diagnose`` reads a file (gateway.offline.recording.to_acceleration),
with the recorded reference. Only the DiagnosisInput goes to diagnose: the terms stay here.

Parameter checks (``CHECKS``): each effect is checked on one or two of the parameters
diagnose reports, against the value the simulation used. An estimate passes when

    |estimate − truth| ≤ max(rel_tol · |truth|, abs_tol)

Tolerances come from the errors measured over benchmark seeds 0–19 (the tests use
seeds 9000+; the benchmark prints medians and 90th percentiles over 100 seeds). Rule:
the larger of 5 % and twice the largest relative error seen, rounded up to 5 %; no
tolerance was widened for a single seed.

| effect             | diagnose key           | truth (simulation)                | largest seen | p90    | rel_tol |
| ------------------ | ---------------------- | --------------------------------- | ------------ | ------ | ------- |
| scale_factor       | scale_error_frac       | scale_error_frac                  | 2.0 %        | 1.3 %  | 5 %     |
| tilt               | tilt_coefficient       | gradient_rad_per_m                | 5.2 %        | 2.0 %  | 15 %    |
| cross_axis         | other_axis_gain        | gain                              | 1.5 %        | 0.9 %  | 5 %     |
| temperature_offset | offset_mg_per_c        | offset_g_per_c · 1e3              | 8.3 %        | 4.9 %  | 20 %    |
| vibration          | frequency_hz           | frequency_hz                      | 0.03 %       | 0.02 % | 5 %     |
| vibration          | damping_ratio          | damping_ratio                     | 0.2 %        | 0.1 %  | 10 %    |
| bandwidth          | cutoff_hz              | cutoff_hz                         | 0.2 %        | 0.1 %  | 5 %     |
| nonlinearity       | quadratic_per_g        | quadratic_per_g                   | 4.7 %        | 4.1 %  | 10 %    |
| clipping           | upper_g                | limit_g                           | 0.02 %       | 0.01 % | 5 %     |
| clipping           | lower_g                | −limit_g                          | 0.01 %       | 0.01 % | 5 %     |
| bias_random_walk   | random_walk_ug_per_rts | k_g_per_rts · 1e6                 | 25 % (2 of 20 named) | | 50 % |
| reference_delay    | delay_ms               | delay_s · 1e3                     | 0.1 %        | 0.1 %  | 5 %     |
| sample_loss        | lost_fraction          | lost / (received + lost), counted | 0            | 0      | 1 %     |
| timing             | hold_back_ms           | √12·σ of the adapter's waits · 1e3 | –           | 2.3 %  | 5 %     |

timing's row is of the buffered adapter with a stepped host clock (sensor_effects.TimingTerm;
`diagnosis_benchmark --generator own --cases 10 --effects timing`, seeds 0–9: median 0.6 %,
p90 2.3 %; the largest not printed): its 5 % is the rule's floor.

Exceptions to the rule: vibration's damping gets 10 % (two effects at once, vibration
with sample loss, gave 4.5 %); sample_loss is checked against the fraction actually
lost in the recording (lost_before, from the sequence counter), not the drawn rate — a
7.6 s record loses a few dozen samples, so the drawn rate is only their expectation —
and that count is exact, hence 1 %. bias_random_walk's truth is the K of the walk, but
the record holds one realisation over 60 s (240 block means of 0.25 s): the estimate's
own spread is tens of per cent, hence 50 %.

Checked afterwards over seeds 0–99 (benchmark, 2026-11-23, core at 832bbeb): every named
parameter of every effect within these tolerances, except bias_random_walk — named in
6 cases of 100, 5 within 50 % (seed 37: 900 against 551 µg/√s); its tolerance was not
widened for it.

"Positive gain": a signal effect lowers the residual RMS and raises the log-likelihood
(gain["residual_rms_mps2"], gain["loglik"]: before, after); a side effect raises its own
log-likelihood (gain["loglik"]) and reports its residual RMS in its own unit
(residual_rms_s for timing; none for sample loss). The distance gain (gain["distance"]["improvement_mm"])
is recorded but not required: the vibration's ringing integrates to no distance.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from gateway.core.diagnosis import DiagnosisInput, DiagnosisResult, diagnose
from gateway.core.estimator_settings import EstimatorSettings, from_sensor_model
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_effects import EFFECT_SIZES, SCENARIO_FOR, draw_effect
from gateway.core.sensor_model import CALIBRATED_SENSITIVITY_TOLERANCE_FRAC, SensorParams
from gateway.core.simulator import ErrorTerm, simulate
from gateway.offline.recording import Recording, to_acceleration

SENSOR = SensorParams()
STROKES = 4
EFFECTS: tuple[str, ...] = tuple(EFFECT_SIZES)
DRAW_STREAM = 7  # the effect parameters come from default_rng([seed, DRAW_STREAM])


@lru_cache(maxsize=4)
def _profile(scenario: tuple = ("paper", STROKES)):
    name, size = scenario
    if name == "standstill":
        return build_profile(ScenarioSettings(name="standstill", standstill_s=size))
    return build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=size)))


def scenario_for(effect_names: tuple[str, ...]) -> tuple:
    """The record an effect is documented on (sensor_effects.SCENARIO_FOR): the paper's
    strokes, or a standstill for the bias random walk; a pair uses the first's."""
    for name in effect_names:
        if name in SCENARIO_FOR:
            return SCENARIO_FOR[name]
    return ("paper", STROKES)


@lru_cache(maxsize=1)
def estimator_settings() -> EstimatorSettings:
    return from_sensor_model(SENSOR)


def draw_terms(effect_names: tuple[str, ...], seed: int) -> tuple[ErrorTerm, ...]:
    unknown = [n for n in effect_names if n not in EFFECT_SIZES]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {', '.join(EFFECTS)}")
    rng = np.random.default_rng([seed, DRAW_STREAM])
    return tuple(draw_effect(name, rng) for name in effect_names)


# A part as built: the sensitivity within its calibration's ±1 %, the filter capacitor
# within ±10 %, the zero-g offset within ±0.1 g (the data sheet: "large part to part";
# a mount tilted 3° adds 52 mg) — what a real board has; the diagnosis is told the
# nominal part, as a user is. Drawn from default_rng([seed, PART_STREAM]), in that
# order (a seed's sensitivity and capacitor are what they were before the offset was drawn).
PART_STREAM = 8
PART_SENSITIVITY_FRAC = 0.01
PART_CAPACITOR_FRAC = 0.10
PART_OFFSET_G = 0.1


def part_within_tolerance(seed: int) -> SensorParams:
    rng = np.random.default_rng([seed, PART_STREAM])
    s = float(rng.uniform(-PART_SENSITIVITY_FRAC, PART_SENSITIVITY_FRAC))
    c = float(rng.uniform(1.0 - PART_CAPACITOR_FRAC, 1.0 + PART_CAPACITOR_FRAC))
    o = float(rng.uniform(-PART_OFFSET_G, PART_OFFSET_G))
    return replace(SENSOR, x=replace(SENSOR.x, sensitivity_error_frac=s, zero_g_offset_g=o),
                   filter_capacitor_f=SENSOR.filter_capacitor_f * c)


def make_case(effect_names: tuple[str, ...], seed: int,
              adjust: Callable[[ErrorTerm], ErrorTerm] | None = None,
              strokes: StrokeSettings | None = None,
              part: SensorParams | None = None) -> tuple[tuple[ErrorTerm, ...], DiagnosisInput]:
    """A simulated recording with these effects hidden in it: (the terms, what diagnose gets).
    `adjust` changes each drawn term before the simulation (e.g. a slower temperature swing);
    `strokes` replaces the paper's strokes (e.g. a gentler machine); `part` the sensor as
    built (default: the nominal part) — the diagnosis is always told the nominal one."""
    terms = draw_terms(tuple(effect_names), seed)
    if adjust is not None:
        terms = tuple(adjust(t) for t in terms)
    profile = (_profile(scenario_for(tuple(effect_names))) if strokes is None
               else build_profile(ScenarioSettings(strokes=strokes)))
    run = simulate(profile, SENSOR if part is None else part, seed=seed, error_terms=terms)
    rec = Recording(f"<simulated seed {seed}>", {"tick_hz": str(run.tick_hz)},
                    {k: np.asarray(v, dtype=float) for k, v in run.recording_columns().items()}, "raw")
    s = to_acceleration(rec)
    data = DiagnosisInput(
        t_s=s.t_s, acc_mps2=s.acc_mps2, valid=s.valid, lost_before=s.lost_before,
        reference="recorded", ref_pos_m=s.reference["ref_pos_m"], ref_vel_mps=s.reference["ref_vel_mps"],
        ref_acc_mps2=s.reference["ref_acc_mps2"], other_mps2=s.other_axis_mps2, temp_c=s.temp_c,
        t_host_s=s.t_host_s, sensor_bandwidth_hz=SENSOR.bandwidth_hz,
        other_axis_still=True,  # the simulator's other axis never moves, and the case knows it
    )
    return terms, data


def run_diagnosis(data: DiagnosisInput) -> DiagnosisResult:
    return diagnose(data, estimator_settings())


def actual_lost_fraction(data: DiagnosisInput) -> float:
    lost = int(np.asarray(data.lost_before).sum())
    return lost / (len(data) + lost)


@dataclass(frozen=True)
class ParamCheck:
    key: str  # the name in EffectResult.params
    truth: Callable[[ErrorTerm, DiagnosisInput], float]
    rel_tol: float
    abs_tol: float = 0.0

    def tolerance(self, truth: float) -> float:
        return max(self.rel_tol * abs(truth), self.abs_tol)


CHECKS: dict[str, tuple[ParamCheck, ...]] = {
    "scale_factor": (ParamCheck("scale_error_frac", lambda t, d: t.scale_error_frac, 0.05),),
    "tilt": (ParamCheck("tilt_coefficient", lambda t, d: t.gradient_rad_per_m, 0.15),),
    "cross_axis": (ParamCheck("other_axis_gain", lambda t, d: t.gain, 0.05),),
    "temperature_offset": (ParamCheck("offset_mg_per_c", lambda t, d: t.offset_g_per_c * 1e3, 0.20),),
    "vibration": (ParamCheck("frequency_hz", lambda t, d: t.frequency_hz, 0.05),
                  ParamCheck("damping_ratio", lambda t, d: t.damping_ratio, 0.10)),
    "bandwidth": (ParamCheck("cutoff_hz", lambda t, d: t.cutoff_hz, 0.05),),
    "nonlinearity": (ParamCheck("quadratic_per_g", lambda t, d: t.quadratic_per_g, 0.10),),
    "clipping": (ParamCheck("upper_g", lambda t, d: t.limit_g, 0.05),
                 ParamCheck("lower_g", lambda t, d: -t.limit_g, 0.05)),
    "bias_random_walk": (ParamCheck("random_walk_ug_per_rts", lambda t, d: t.k_g_per_rts * 1e6, 0.50),),
    "reference_delay": (ParamCheck("delay_ms", lambda t, d: t.delay_s * 1e3, 0.05),),
    "sample_loss": (ParamCheck("lost_fraction", lambda t, d: actual_lost_fraction(d), 0.01),),
    "timing": (ParamCheck("hold_back_ms", lambda t, d: t.equivalent_hold_back_s() * 1e3, 0.05),),
}
assert set(CHECKS) == set(EFFECTS), "every documented effect needs its parameter check"


@dataclass
class ParamOutcome:
    key: str
    estimate: float
    truth: float
    tolerance: float

    @property
    def abs_error(self) -> float:
        return abs(self.estimate - self.truth)

    @property
    def rel_error(self) -> float:
        return self.abs_error / abs(self.truth) if self.truth else math.inf

    @property
    def ok(self) -> bool:
        return bool(self.abs_error <= self.tolerance)


@dataclass
class EffectOutcome:
    name: str
    named: bool
    params: list[ParamOutcome] = field(default_factory=list)
    gain_positive: bool = False
    gain_why: str = ""
    distance_improvement_mm: float = float("nan")
    # judged as the setup's property (a part as built whose total sensitivity error is
    # within the calibration's tolerance): `named` then means "reported as the setup's"
    as_setup: bool = False

    @property
    def params_ok(self) -> bool:
        return self.named and all(p.ok for p in self.params)

    @property
    def worst_rel_error(self) -> float:
        return max((p.rel_error for p in self.params), default=float("nan"))


@dataclass
class CaseOutcome:
    hidden: tuple[str, ...]
    seed: int
    named: tuple[str, ...]
    effects: dict[str, EffectOutcome]
    residual_white: bool
    seconds: float = float("nan")

    @property
    def wrong(self) -> tuple[str, ...]:
        """Effects named that were not hidden."""
        return tuple(n for n in self.named if n not in self.hidden)

    def describe(self) -> str:
        rows = [f"hidden {list(self.hidden)} seed {self.seed}: named {list(self.named)}, "
                f"residual white {self.residual_white}"]
        for e in self.effects.values():
            ps = ", ".join(f"{p.key} {p.estimate:.5g} vs {p.truth:.5g} (±{p.tolerance:.3g})" for p in e.params)
            rows.append(f"  {e.name}: named {e.named}; {ps or 'no parameters'}; gain positive "
                        f"{e.gain_positive} {e.gain_why}; distance improvement {e.distance_improvement_mm:.3g} mm")
        return "\n".join(rows)


def _gain_check(effect) -> tuple[bool, str]:
    g = effect.gain
    ll_before, ll_after = g["loglik"]
    # one residual RMS, its unit in the key (timing's is seconds); sample loss has none
    rms_keys = sorted(k for k in g if k.startswith("residual_rms"))
    rms_key = "residual_rms_s" if effect.name == "timing" else "residual_rms_mps2"
    expected = [] if effect.name == "sample_loss" else [rms_key]
    if rms_keys != expected:
        return False, f"(residual RMS keys {rms_keys}, expected {expected})"
    if effect.kind == "signal":
        rms_before, rms_after = g["residual_rms_mps2"]
        ok = rms_after < rms_before and ll_after > ll_before
        return ok, f"(rms {rms_before:.4g}→{rms_after:.4g} m/s², loglik {ll_before:.6g}→{ll_after:.6g})"
    return ll_after > ll_before, f"(loglik {ll_before:.6g}→{ll_after:.6g})"


def part_scale_error_frac(term: ErrorTerm, part: SensorParams | None) -> float:
    """A hidden scale error as the recording has it: on a part as built, its own
    sensitivity error multiplies in."""
    own = 0.0 if part is None else part.x.sensitivity_error_frac
    return (1.0 + own) * (1.0 + term.scale_error_frac) - 1.0


def judge(hidden: tuple[str, ...], terms: tuple[ErrorTerm, ...], data: DiagnosisInput,
          result: DiagnosisResult, seed: int = -1, seconds: float = float("nan"),
          part: SensorParams | None = None) -> CaseOutcome:
    """What diagnose got right about the hidden effects. On a part as built (`part`), a
    hidden scale error is judged against the part's total sensitivity error; where that
    lies within the calibration's tolerance the right answer is the setup's property (the
    outcome says `as_setup`), not a name."""
    found = {e.name: e for e in result.effects}
    setup = {s["name"]: s for s in result.setup}
    outcomes = {}
    for name, term in zip(hidden, terms, strict=False):
        e = found.get(name)
        total_scale = part_scale_error_frac(term, part) if name == "scale_factor" else float("nan")
        if part is not None and abs(total_scale) <= CALIBRATED_SENSITIVITY_TOLERANCE_FRAC:
            s = setup.get(name)
            out = EffectOutcome(name, e is None and s is not None, as_setup=True)
            if s is not None:
                check = CHECKS[name][0]
                out.params.append(ParamOutcome(check.key, float(s["params"][check.key][0]), total_scale,
                                               check.tolerance(total_scale)))
            outcomes[name] = out
            continue
        out = EffectOutcome(name, e is not None)
        if e is not None:
            for check in CHECKS[name]:
                truth = total_scale if part is not None and name == "scale_factor" else float(check.truth(term, data))
                estimate = float(e.params[check.key][0]) if check.key in e.params else float("nan")
                out.params.append(ParamOutcome(check.key, estimate, truth, check.tolerance(truth)))
            out.gain_positive, out.gain_why = _gain_check(e)
            dist = e.gain.get("distance", {})
            if dist.get("available"):
                out.distance_improvement_mm = float(dist["improvement_mm"])
        outcomes[name] = out
    return CaseOutcome(tuple(hidden), seed, tuple(e.name for e in result.effects), outcomes,
                       result.residual_white, seconds)


def run_case(hidden: tuple[str, ...], seed: int, parts_within_tolerance: bool = False,
             jerk_mps3: float = 0.0, dcm_reading: str = "mean") -> CaseOutcome:
    """Build, diagnose and judge one case (also what a benchmark worker runs); optionally
    on a part as built (part_within_tolerance) instead of the nominal one, with the
    strokes driven jerk-limited (an S-curve drive; a standstill case has no strokes), and
    with the modulator reading where each duty cycle ends (SensorParams.dcm_reading)."""
    t0 = time.perf_counter()
    terms, data, part = build_case(hidden, seed, parts_within_tolerance, jerk_mps3, dcm_reading)
    result = run_diagnosis(data)
    return judge(tuple(hidden), terms, data, result, seed, time.perf_counter() - t0, part)


def build_case(hidden: tuple[str, ...], seed: int, parts_within_tolerance: bool = False,
               jerk_mps3: float = 0.0, dcm_reading: str = "mean", zero_g_offset_g: float | None = None):
    """The benchmark's case with these options (run_case's): (terms, what diagnose gets, the part or None).
    zero_g_offset_g: the same part but for its zero-g offset (a reading aid's question)."""
    part = part_within_tolerance(seed) if parts_within_tolerance else None
    if dcm_reading != "mean":
        part = replace(part or SENSOR, dcm_reading=dcm_reading)
    if zero_g_offset_g is not None:
        part = part or SENSOR
        part = replace(part, x=replace(part.x, zero_g_offset_g=zero_g_offset_g))
    scenario = scenario_for(tuple(hidden))
    strokes = (StrokeSettings(strokes=scenario[1], jerk_mps3=jerk_mps3)
               if jerk_mps3 > 0 and scenario[0] == "paper" else None)
    terms, data = make_case(tuple(hidden), seed, part=part, strokes=strokes)
    return terms, data, part
