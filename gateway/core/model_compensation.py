"""The extended sensor model a diagnosis found, applied to measurements (written once).

`adxlgw diagnose --model-out M.json` writes the effects it accepted, with their
parameters in SI units; `adxlgw estimate --model M.json` and the daemon
(`[calibration] model = "M.json"`) read it here and correct the measured acceleration
before the estimator sees it. The diagnosis measures its own distance gain with the same functions
(gateway/core/diagnosis/signal_effects.py calls `compensate_term`), so what is measured
there is what a user gets.

Each term undoes what its effect adds to the reading:

| term | the effect | compensation | needs |
| --- | --- | --- | --- |
| scale_factor | reads (1 + s)·a | a / (1 + s) | – |
| tilt | + g·κ·x (tilt varying along the path) | − g·κ·x̂ | the position |
| motion_offset | + b while the axis moves | − b where the estimate moves | the standstill flags |
| temperature_offset | + k·(T_die − T_ref), T_die: T lagged by τ | − k·(T_die − T_ref) | the temperature |
| cross_talk | + c·(other axis's motion) | − c·(other − its level at rest) | the other axis |
| bandwidth, output_filter | an extra pole | the estimator's sensor lag + Δτ | – (a setting) |

What needs the estimate (position, standstill) is corrected with the estimate's own,
re-estimated until it settles (`compensated_estimate`): the estimate without the
correction can be metres off, and one pass from there overshoots. Where the passes do
not settle (the estimate's own standstill decisions flip with the correction) the
result says so: its last pass is one of the answers the model allows, not the answer. Terms with no
correction (a ringing that integrates to nothing, clipped samples, a reference delay)
are kept in the file for the record and listed as `not_compensated`.

The daemon corrects one sample at a time, as it arrives (`sample_terms` +
`term_correction`, called by gateway/daemon/sample_loop.py's compiled loop): only
terms whose correction needs nothing from the future. Scale, temperature (the board's
latest report) and the motion offset (the filter's own standstill flag of the previous
sample) qualify; `term_correction` is the one formula for both paths. A temperature
term with a die lag (τ > 0) is causal too, but the compiled loop keeps no state for the
lag's filter: refused there, applied offline (`estimate --model`). The tilt needs
the position along the path from the recording's origin (the daemon's origin moves with
every tare and start-over) and the cross-talk the other axis's level over all the
recording's rests: neither is known causally, and a model with them is refused
(`sample_path_refusal`).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from gateway.core.jit import jit
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G

MODEL_FORMAT = "adxlgw-sensor-model"
MODEL_VERSION = 1
# A correction that needs the estimate is re-estimated until a pass moves the position by
# less than SETTLED_M anywhere: a tenth of the millimetre every distance table prints
# (`estimate`, the diagnosis's gains, docs/diagnosis.md), so a further pass changes no
# printed digit beyond its rounding. MAX_PASSES bounds the work where the passes do not
# settle (they alternate: more passes only repeat the answers, and the result says so):
# passes that at least halve each time settle within it from a first move of up to
# 2¹¹ × 0.1 mm = 0.2 m; slower ones are reported as not settled, not waited for.
SETTLED_M = 1e-4
MAX_PASSES = 12


@dataclass(frozen=True)
class ModelTerm:
    name: str
    params: dict[str, float]  # SI units, the diagnosis's parameter names


@dataclass(frozen=True)
class SensorModel:
    terms: tuple[ModelTerm, ...]
    source: str = ""
    notes: tuple[str, ...] = ()

    @property
    def uses_estimate(self) -> bool:
        return any(t.name in NEEDS_ESTIMATE for t in self.terms)

    @property
    def not_compensated(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms if t.name not in COMPENSATED and t.name not in LAG_TERMS)

    def to_dict(self) -> dict:
        return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "source": self.source,
                "effects": [{"name": t.name, "params": dict(t.params)} for t in self.terms],
                "not_compensated": list(self.not_compensated), "notes": list(self.notes)}


@dataclass
class SampleContext:
    """What a correction may use beside the measured acceleration, one entry per sample."""

    t_s: np.ndarray
    other_mps2: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    pos_m: np.ndarray | None = None  # the estimate's position
    moving: np.ndarray | None = None  # the estimate's (or the reference's) motion flags
    rest: np.ndarray | None = None  # where the axis is known at rest (levels are read there)
    extra: dict = field(default_factory=dict)


class ModelError(ValueError):
    """A model file that cannot be used; the message names what and where."""


def other_axis_motion(other: np.ndarray, rest: np.ndarray | None) -> np.ndarray:
    """The other axis less its level at rest (its offset and gravity share): its motion."""
    o = np.asarray(other, dtype=float)
    ok = np.isfinite(o)
    at_rest = ok & rest if rest is not None and np.any(ok & rest) else ok
    level = float(np.median(o[at_rest])) if at_rest.any() else 0.0
    return np.where(ok, o - level, 0.0)


def die_temperature_c(t_s: np.ndarray, temp_c: np.ndarray, lag_s: float) -> np.ndarray:
    """The accelerometer die's temperature from the board's thermometer: the board's
    temperature through a first-order thermal lag τ = lag_s (the package's heat capacity
    behind its thermal resistance to the board; the range: judgement.MAX_DIE_LAG_S);
    τ = 0: the reading itself.

    The board's history before the record is not in it: the die is taken as settled at
    the board's first reading (a machine that starts from rest). Where the board was
    already swinging, the start is wrong for the record's first few τ: on the own
    simulator's 6 s swing with the die 2 s behind in its periodic steady state, the fit
    then trades k against τ while the die's offset swing itself is found (docs/diagnosis.md
    §3; why not a fitted start: decisions/0192).

    Exact for a temperature linear between the samples' own times, whatever their spacing
    (gaps, bursts, repeated times: no time passes, nothing changes). NaN where temp_c is
    NaN."""
    temp = np.asarray(temp_c, dtype=float)
    t = np.asarray(t_s, dtype=float)
    ok = np.isfinite(temp) & np.isfinite(t)
    if lag_s <= 0.0 or np.count_nonzero(ok) < 2:
        return temp.copy()
    out = np.full(temp.shape, np.nan)
    out[ok] = _first_order_lag(t[ok], temp[ok], float(lag_s))
    return out


@jit
def _first_order_lag(t, x, tau):
    """y' = (x − y)/τ, y(t₀) = x(t₀), x linear between samples; over a step h:
    y₊ = a·y + (1 − c)·x₊ + (c − a)·x, a = e^(−h/τ), c = τ(1 − a)/h."""
    y = np.empty(x.size)
    y[0] = x[0]
    for k in range(1, x.size):
        h = t[k] - t[k - 1]
        if h <= 0.0:
            y[k] = y[k - 1]
            continue
        a = math.exp(-h / tau)
        c = tau * (1.0 - a) / h
        y[k] = a * y[k - 1] + (1.0 - c) * x[k] + (c - a) * x[k - 1]
    return y


def _temperature_term(t_s: np.ndarray, temp: np.ndarray, ref_c: float, lag_s: float) -> np.ndarray:
    return np.nan_to_num(die_temperature_c(t_s, temp, lag_s) - ref_c, nan=0.0)


# the terms a sample can be corrected for as it arrives (the daemon's compiled loop):
# codes in a float array [code, p0, p1] per term
TERM_SCALE = 1.0
TERM_MOTION_OFFSET = 2.0
TERM_TEMPERATURE = 3.0


def term_correction(code: float, p0: float, acc, moving, temp_dev_c):
    """The reading less one causal term, elementwise: one sample (the daemon, compiled)
    or whole arrays (offline). moving: 1.0 where the axis moves; temp_dev_c: the
    temperature less the term's reference (0 where unknown)."""
    if code == TERM_SCALE:
        return acc / (1.0 + p0)
    if code == TERM_MOTION_OFFSET:
        return acc - p0 * moving
    if code == TERM_TEMPERATURE:
        return acc - p0 * temp_dev_c
    return acc


def compensate_term(name: str, params: dict[str, float], acc: np.ndarray, ctx: SampleContext) -> np.ndarray:
    """acc with one term's reading removed (acc unchanged for a term with no correction)."""
    if name == "scale_factor":
        return term_correction(TERM_SCALE, params["scale_error_frac"], acc, 0.0, 0.0)
    if name == "tilt":
        pos = ctx.pos_m if ctx.pos_m is not None else np.zeros_like(acc)
        return acc - params["tilt_gradient_rad_per_m"] * G * pos
    if name == "motion_offset":
        moving = ctx.moving if ctx.moving is not None else np.zeros(acc.size, dtype=bool)
        return term_correction(TERM_MOTION_OFFSET, params["offset_mps2"], acc, moving.astype(float), 0.0)
    if name == "temperature_offset":
        if ctx.temp_c is None:
            raise ModelError("temperature_offset: the recording has no temperature (temp_c) to correct with")
        # a file written before the die's lag was fitted has none: the board's reading
        return term_correction(TERM_TEMPERATURE, params["offset_mps2_per_c"], acc, 0.0,
                               _temperature_term(ctx.t_s, ctx.temp_c, params.get("reference_c", 0.0),
                                                 params.get("die_lag_s", 0.0)))
    if name == "cross_talk":
        if ctx.other_mps2 is None:
            raise ModelError("cross_talk: the recording has no other axis to correct with")
        return acc - params["gain"] * other_axis_motion(ctx.other_mps2, ctx.rest)
    return acc


def extra_sensor_lag_s(model: SensorModel, nominal_bandwidth_hz: float | None) -> float:
    """The lag the model's filter terms add to the estimator's own sensor lag."""
    lag = 0.0
    for t in model.terms:
        if t.name == "bandwidth":
            lag += 1.0 / (2.0 * math.pi * t.params["cutoff_hz"])
        elif t.name == "output_filter" and nominal_bandwidth_hz:
            lag += 1.0 / (2.0 * math.pi * t.params["bandwidth_hz"]) - 1.0 / (2.0 * math.pi * nominal_bandwidth_hz)
    return lag


def compensate(model: SensorModel, acc: np.ndarray, ctx: SampleContext) -> np.ndarray:
    """One pass of every term over acc, in the file's order (the diagnosis's acceptance order)."""
    out = np.asarray(acc, dtype=float)
    for t in model.terms:
        out = compensate_term(t.name, t.params, out, ctx)
    return out


@dataclass
class CompensatedEstimate:
    """The estimate on the corrected measurement, and whether the correction settled.

    A term that needs the estimate (the tilt's position, the motion offset's flags) is
    corrected with the previous pass's estimate; the passes need not converge. Where the
    estimate's own standstill decisions flip with the correction, the passes can
    alternate between two estimates (seen on the Leiria robot's horizontal moves without
    the hint: final positions 186 mm apart, pass after pass). Then the last pass is one
    of several answers the model gives, not the model's answer: `settled` is False and
    `last_step_m` says by how much the position still moved (docs/diagnosis.md §6)."""

    track: object
    acc_mps2: np.ndarray
    passes: int
    last_step_m: float  # the largest change of the position in the last pass (0: one pass was enough)

    @property
    def settled(self) -> bool:
        return self.last_step_m < SETTLED_M

    def describe(self) -> str:
        """One line for the user: the passes made, and a correction that did not settle."""
        if self.passes == 1:
            return ""
        if self.settled:
            return f"{self.passes} passes with the estimate's position"
        return (f"did not settle after {self.passes} passes with the estimate's position: the last pass still "
                f"moved the position by up to {self.last_step_m * 1e3:.1f} mm, so the result is one of the "
                "estimates the model allows, not a determined one")


def _largest_move_m(before, after) -> float:
    """How far the position moved from one pass to the next, at most, over the record."""
    a, b = np.asarray(after.pos_m, dtype=float), np.asarray(before.pos_m, dtype=float)
    return float(np.max(np.abs(a - b))) if a.size else 0.0


def settle_correction(correct: Callable[[object | None], np.ndarray], run: Callable[[np.ndarray], object | None],
                      start: object | None = None) -> CompensatedEstimate:
    """The one loop for a correction that needs the estimate it corrects (written once:
    `compensated_estimate` for `estimate --model`, the diagnosis's gain.EstimatePlan).

    correct(track) returns the corrected acceleration given the previous pass's estimate
    (None: no estimate yet); run(acc) returns the estimate (pos_m, standstill),
    or None where the estimator cannot make one. `start` is the estimate before any
    correction when the caller has it (then the first pass corrects with it). Pass k
    corrects with pass k−1's estimate and runs it, until a pass moves the position by less
    than SETTLED_M or MAX_PASSES passes are made (then `settled` is False: the passes
    alternate or creep, and the last is one of the answers the model allows). The
    acceleration returned is the one the returned track was run on. A run that fails
    ends the passes (track None, last_step_m NaN: neither settled nor an answer)."""
    previous = start
    acc = correct(previous)
    track = run(acc)
    passes, step = 1, math.inf
    while track is not None:
        if previous is not None:
            step = _largest_move_m(previous, track)
            if step < SETTLED_M:
                break
        if passes == MAX_PASSES:
            break
        previous = track
        acc = correct(previous)
        track = run(acc)
        passes += 1
    if track is None:
        step = math.nan
    return CompensatedEstimate(track, acc, passes, step)


def compensated_estimate(model: SensorModel, acc: np.ndarray, ctx: SampleContext,
                         run: Callable[[np.ndarray], object]) -> CompensatedEstimate:
    """The estimate on the corrected acceleration. run(acc) returns a track with pos_m and
    standstill; terms that need the estimate take it from the previous pass
    (`settle_correction`); a model without such terms is one pass."""
    if not model.uses_estimate:
        corrected = compensate(model, acc, ctx)
        return CompensatedEstimate(run(corrected), corrected, 1, 0.0)

    def correct(track) -> np.ndarray:
        if track is not None:
            ctx.pos_m = np.asarray(track.pos_m, dtype=float)
            ctx.moving = ~np.asarray(track.standstill, dtype=bool)
        return compensate(model, acc, ctx)

    return settle_correction(correct, run)


NEEDS_ESTIMATE = ("tilt", "motion_offset")
COMPENSATED = ("scale_factor", "tilt", "motion_offset", "temperature_offset", "cross_talk")
LAG_TERMS = ("bandwidth", "output_filter")


def model_from_dict(doc: dict, where: str) -> SensorModel:
    if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT:
        raise ModelError(f"{where}: not an {MODEL_FORMAT} file (written by adxlgw diagnose --model-out)")
    if doc.get("version") != MODEL_VERSION:
        raise ModelError(f"{where}: version {doc.get('version')!r}; this gateway reads version {MODEL_VERSION}")
    terms = []
    for i, e in enumerate(doc.get("effects", [])):
        if not isinstance(e, dict) or not isinstance(e.get("name"), str) or not isinstance(e.get("params"), dict):
            raise ModelError(f"{where}: effects[{i}]: needs a name and params")
        params = {}
        for k, v in e["params"].items():
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ModelError(f"{where}: effects[{i}] ({e['name']}): {k} = {v!r} is not a finite number")
            params[k] = float(v)
        terms.append(ModelTerm(e["name"], params))
    return SensorModel(tuple(terms), str(doc.get("source", "")), tuple(doc.get("notes", ())))


def physical_ranges() -> dict[str, tuple[str, float, float, str]]:
    """{effect: (parameter, lowest, highest, source)}: what a part, mount or machine can
    have — the diagnosis's own ranges (gateway/core/diagnosis/judgement.py, imported here
    when a file is checked: the diagnosis imports this module)."""
    from gateway.core.diagnosis import judgement as J

    inf = math.inf
    return {
        "scale_factor": ("scale_error_frac", -J.MAX_SCALE_ERROR_FRAC, J.MAX_SCALE_ERROR_FRAC,
                         "data sheet: sensitivity 10-15 %/g"),
        "nonlinearity": ("quadratic_per_g", -J.MAX_QUADRATIC_PER_G, J.MAX_QUADRATIC_PER_G,
                         "data sheet: ~0.2 % of full scale"),
        "tilt": ("tilt_gradient_rad_per_m", -J.MAX_TILT_RAD_PER_M, J.MAX_TILT_RAD_PER_M,
                 "a rail or arm turning the sensor"),
        "temperature_offset": ("offset_mps2_per_c", -J.MAX_OFFSET_MG_PER_C * 1e-3 * G,
                               J.MAX_OFFSET_MG_PER_C * 1e-3 * G, "data sheet: order of 1 mg/°C"),
        "motion_offset": ("offset_mps2", -G * math.sin(math.radians(J.MAX_TILT_IN_MOTION_DEG)),
                          G * math.sin(math.radians(J.MAX_TILT_IN_MOTION_DEG)), "a tool tilting ≤ 5° under its drive"),
        "cross_talk": ("gain", -J.MAX_CROSS_GAIN, J.MAX_CROSS_GAIN, "±2 % cross-axis + a few degrees of misalignment"),
        "bandwidth": ("cutoff_hz", J.MIN_BANDWIDTH_HZ, inf, "a lower pole swallows the motion itself"),
        "output_filter": ("bandwidth_hz", J.MIN_BANDWIDTH_HZ, inf, "a lower pole swallows the motion itself"),
        "reference_delay": ("delay_s", -J.MAX_DELAY_S, J.MAX_DELAY_S, "beyond: a clock problem, not a lag"),
        "vibration": ("damping_ratio", 0.0, J.MAX_DAMPING_RATIO, "above it does not ring"),
        "reading_instant": ("edge_fraction", 0.0, 1.0, "within the sample's own period"),
        "clipping": ("upper_mps2", 0.0, inf, "a saturation limit above zero"),
    }


def check_terms(model: SensorModel, where: str) -> None:
    """Every term known, its parameters present and within its physical range (checked
    once, when the file is read); ModelError naming the file, the term and the key."""
    from gateway.core.diagnosis.judgement import MAX_DIE_LAG_S  # (as physical_ranges: imported here)

    ranges = physical_ranges()
    for i, t in enumerate(model.terms):
        if t.name not in ranges:
            raise ModelError(f"{where}: effects[{i}]: unknown effect {t.name!r} "
                             f"(known: {', '.join(ranges)})")
        key, lo, hi, source = ranges[t.name]
        if key not in t.params:
            raise ModelError(f"{where}: effects[{i}] ({t.name}): parameter {key} is missing")
        if not lo <= t.params[key] <= hi:
            raise ModelError(f"{where}: effects[{i}] ({t.name}): {key} = {t.params[key]:g} is outside its "
                             f"physical range [{lo:g}, {hi:g}] ({source})")
        lag = t.params.get("die_lag_s", 0.0) if t.name == "temperature_offset" else 0.0
        if not 0.0 <= lag <= MAX_DIE_LAG_S:
            raise ModelError(f"{where}: effects[{i}] ({t.name}): die_lag_s = {lag:g} is outside its physical "
                             f"range [0, {MAX_DIE_LAG_S:g}] (a ceramic package's thermal time constant)")
        try:
            compensate_term(t.name, t.params, np.zeros(2), SampleContext(np.zeros(2), np.zeros(2), np.zeros(2)))
        except KeyError as err:
            raise ModelError(f"{where}: effects[{i}] ({t.name}): parameter {err.args[0]} is missing") from err


# why a term cannot be applied one sample at a time, as it arrives (module docstring)
NOT_CAUSAL = {
    "tilt": "its correction needs the position along the path from the recording's origin, and the "
            "daemon's position origin moves with every tare and start-over",
    "cross_talk": "its correction needs the other axis's level over all the recording's rests, which a "
                  "sample path does not know when the sample arrives",
}


def sample_path_refusal(model: SensorModel, where: str) -> str | None:
    """Why the daemon cannot apply this model (None: it can): a term it would have to
    correct with what it does not know yet. Terms with no correction are kept for the
    record, as offline."""
    for t in model.terms:
        if t.name in NOT_CAUSAL:
            return (f"{where}: {t.name}: cannot be applied as samples arrive: {NOT_CAUSAL[t.name]} "
                    "(apply it offline: adxlgw estimate --model)")
        if t.name == "temperature_offset" and t.params.get("die_lag_s", 0.0) > 0.0:
            return (f"{where}: {t.name}: its die lag ({t.params['die_lag_s']:g} s) needs a filter state the "
                    "daemon's sample loop does not keep (apply it offline: adxlgw estimate --model)")
    return None


def sample_terms(model: SensorModel) -> np.ndarray:
    """The causal terms as rows [code, p0, p1] in the file's order, for the compiled
    sample loop (term_correction); call sample_path_refusal first."""
    rows = []
    for t in model.terms:
        if t.name == "scale_factor":
            rows.append((TERM_SCALE, t.params["scale_error_frac"], 0.0))
        elif t.name == "motion_offset":
            rows.append((TERM_MOTION_OFFSET, t.params["offset_mps2"], 0.0))
        elif t.name == "temperature_offset":
            rows.append((TERM_TEMPERATURE, t.params["offset_mps2_per_c"], t.params.get("reference_c", 0.0)))
    return np.array(rows, dtype=float).reshape(-1, 3)


def settings_with_model_lag(settings, model: SensorModel, nominal_bandwidth_hz: float | None):
    """The estimator's settings with the model's filter terms' lag added (estimate
    --model and the daemon alike)."""
    lag = extra_sensor_lag_s(model, nominal_bandwidth_hz)
    return replace(settings, sensor_lag_s=settings.sensor_lag_s + lag) if lag else settings
