"""Recordings with one hidden effect (or none), made by the independent generator.

    truth, data = make_case("vibration", seed)     # the effect is drawn here...
    result = diagnose(data, settings)               # ...diagnose gets the recording only
    outcome = judge(truth, result)

A case: 6 strokes of 30 cm on x (S-curves, 1 m/s, 10 m/s², 400 m/s³) with rests of
0.6–1 s, the other axis (y) making 2–3 moves of its own — except for cross_axis, where y
stands still and the case says so, as a user would (`--other-axis-still`); for
bias_random_walk a 60 s standstill. Part, noise, link and effect parameters come from
numpy.random.default_rng([seed, 14]). Effect sizes were chosen from the data sheet and
board facts before any diagnosis ran on this generator (EFFECT_SIZES below); "hum" is
outside the diagnosis's vocabulary (50 Hz mains pickup at the element): the right
answer for it is "unexplained structure", no name.

The raw recording goes through gateway.offline.recording.to_acceleration exactly as a file
would. This package never imports gateway.core.simulator, sensor_effects or
motion_profiles (tests/test_diagnosis.py checks).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gateway.commands.diagnose import build_input
from gateway.offline.recording import Recording, to_acceleration
from testing.independent_generator import board
from testing.independent_generator.motion import MotionPlan, MoveLimits, strokes

STREAM = 14
STROKES = 6
STANDSTILL_S = 60.0
# name → how it is drawn (uniform on each range; ± means a random sign too)
EFFECT_SIZES = {
    "scale_factor": "±2–5 % beyond the part's own (within 1 %)",
    "tilt": "±0.03–0.09 rad/m",
    "cross_axis": "±2–6 % of x on a still y",
    "temperature_offset": "±0.5–2 mg/°C, board swinging ±4 °C",
    "vibration": "15–45 Hz, ζ 0.03–0.12",
    "bandwidth": "an extra pole at 8–25 Hz",
    "nonlinearity": "±0.5–1.5 %/g",
    "clipping": "0.6–0.9 g",
    "bias_random_walk": "0.3–0.8 mg/√s (60 s standstill)",
    "reference_delay": "±5–15 ms",
    "sample_loss": "0.3–1.5 % of frames, bursts of 1–3",
    "timing": "USB latency timer 4–16 ms",
    "hum": "50 Hz, 4–10 mg (outside the vocabulary)",
}
IN_VOCABULARY = tuple(n for n in EFFECT_SIZES if n != "hum")


def _signed(rng, lo, hi):
    return float(rng.uniform(lo, hi) * rng.choice((-1.0, 1.0)))


def draw(name: str | None, rng: np.random.Generator) -> dict:
    """The hidden effect's parameters (empty for a clean case)."""
    if name is None:
        return {}
    d = {
        "scale_factor": lambda: {"scale": _signed(rng, 0.02, 0.05)},
        "tilt": lambda: {"kappa": _signed(rng, 0.03, 0.09)},
        "cross_axis": lambda: {"k": _signed(rng, 0.02, 0.06)},
        "temperature_offset": lambda: {"g_per_c": _signed(rng, 0.5e-3, 2e-3)},
        "vibration": lambda: {"f_hz": rng.uniform(15, 45), "zeta": rng.uniform(0.03, 0.12)},
        "bandwidth": lambda: {"fc_hz": rng.uniform(8, 25)},
        "nonlinearity": lambda: {"beta": _signed(rng, 0.005, 0.015)},
        "clipping": lambda: {"limit_g": rng.uniform(0.6, 0.9)},
        "bias_random_walk": lambda: {"k_g_per_rts": rng.uniform(0.3e-3, 0.8e-3)},
        "reference_delay": lambda: {"delay_s": _signed(rng, 5e-3, 15e-3)},
        "sample_loss": lambda: {"fraction": rng.uniform(0.003, 0.015)},
        "timing": lambda: {"hold_s": rng.uniform(4e-3, 16e-3)},
        "hum": lambda: {"amp_g": rng.uniform(4e-3, 10e-3), "f_hz": 50.0},
    }
    if name not in d:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECT_SIZES)}")
    return {k: float(v) for k, v in d[name]().items()}


def _other_axis_plan(rng, end_s: float) -> MotionPlan:
    plan = MotionPlan(MoveLimits(), [])
    n = int(rng.integers(2, 4))
    starts = np.sort(rng.uniform(1.0, max(1.5, end_s - 1.5), n))
    t_free = 0.0
    for s in starts:
        s = max(s, t_free + 0.2)
        plan.moves.append((float(s), _signed(rng, 0.1, 0.2)))
        t_free = plan.end_s()
    return plan


@dataclass
class Case:
    effect: str | None
    seed: int
    params: dict
    part: board.Part
    other_axis_still: bool
    recording: Recording
    data: object = field(repr=False, default=None)  # the DiagnosisInput


def make_case(effect: str | None, seed: int) -> Case:
    rng = np.random.default_rng([seed, STREAM])
    params = draw(effect, rng)
    part = board.Part.draw(rng)
    if effect == "bias_random_walk":
        x_plan = MotionPlan(MoveLimits(), [])
        duration = STANDSTILL_S
    else:
        x_plan = strokes(rng, STROKES)
        duration = x_plan.end_s() + 1.0
    still_y = effect in ("cross_axis", "bias_random_walk")
    y_plan = MotionPlan(MoveLimits(), []) if still_y else _other_axis_plan(rng, duration)

    rise = board.periods(part, duration, rng)
    t_fine = np.arange(0.0, rise[-1] + 0.01, 1.0 / board.FINE_HZ)
    x_pos, _, x_acc = x_plan.evaluate(t_fine)
    _, _, y_acc = y_plan.evaluate(t_fine)
    ax_g, ay_g = x_acc / board.G, y_acc / board.G

    # the element's input, in g: motion plus what the hidden effect adds at the element
    if effect == "vibration":
        ax_g = board.resonance(ax_g, params["f_hz"], params["zeta"], board.FINE_HZ)
    if effect == "bandwidth":
        ax_g = board.rc_lowpass(ax_g, params["fc_hz"], board.FINE_HZ)
    if effect == "tilt":
        ax_g = ax_g + np.sin(params["kappa"] * x_pos)
    if effect == "nonlinearity":
        ax_g = ax_g + params["beta"] * ax_g**2
    if effect == "cross_axis":
        ay_g = ay_g + params["k"] * ax_g
    # board temperature: a slow 0.3 °C creep, or a ±4 °C swing over the record
    temp_true = 25.0 + (4.0 * np.sin(2 * math.pi * t_fine / duration) if effect == "temperature_offset"
                        else 0.3 * t_fine / duration)
    if effect == "temperature_offset":
        ax_g = ax_g + params["g_per_c"] * (temp_true - 25.0)
    if effect == "hum":
        ax_g = ax_g + params["amp_g"] * np.sin(2 * math.pi * params["f_hz"] * t_fine + rng.uniform(0, 2 * math.pi))
    if effect == "bias_random_walk":
        steps = params["k_g_per_rts"] * math.sqrt(1.0 / board.FINE_HZ) * rng.standard_normal(t_fine.size)
        ax_g = ax_g + np.cumsum(steps)
    # zero drift: a few hundred µg over the record
    ax_g = ax_g + rng.uniform(-3e-4, 3e-4) * t_fine / duration

    fc = part.bandwidth_hz
    yx = board.rc_lowpass(ax_g + board.element_noise(t_fine.size, rng), fc, board.FINE_HZ)
    yy = board.rc_lowpass(ay_g + board.element_noise(t_fine.size, rng), fc, board.FINE_HZ)
    s_x = part.s_x * (1.0 + params.get("scale", 0.0))
    clip = params.get("limit_g", 2.0)
    fall_x = board.duty_cycles(t_fine, yx, rise, part.d0_x, s_x, clip)
    fall_y = board.duty_cycles(t_fine, yy, rise, part.d0_y, part.s_y)
    t1x, t1y, t2 = board.capture(rise, fall_x, fall_y, part.tick_phase)
    n = t2.size
    host = board.host_arrivals(rise[1:], rng, params.get("hold_s", 0.0))
    seq = np.arange(n) % 65536
    keep = np.ones(n, dtype=bool)
    if effect == "sample_loss":
        lost_target = int(round(params["fraction"] * n))
        while (~keep).sum() < lost_target:
            k = int(rng.integers(10, n - 10))
            keep[k:k + int(rng.integers(1, 4))] = False
    # the reference: the controller's motion at each period's start (board time from the
    # first sample on); a lagging reference logs the motion d late
    start = rise[:-1] - rise[0]
    ref_t = start - params.get("delay_s", 0.0)
    rp, rv, ra = x_plan.evaluate(ref_t + rise[0])
    # the STATUS temperature: once per second, 0.01 °C
    t_status = np.floor(start)
    temp_col = np.round(np.interp(t_status, t_fine, temp_true), 2)
    cols = {"seq": seq, "t1x": t1x, "t1y": t1y, "t2": t2, "flags": np.zeros(n), "t_host_s": host,
            "temp_c": temp_col, "ref_pos_m": rp, "ref_vel_mps": rv, "ref_acc_mps2": ra}
    cols = {k: np.asarray(v, dtype=float)[keep] for k, v in cols.items()}
    rec = Recording(f"<independent seed {seed}>", {"tick_hz": str(board.TICK_HZ), "source": "independent"},
                    cols, "raw")
    case = Case(effect, seed, params, part, still_y, rec)
    # exactly what `adxlgw diagnose FILE.csv [--other-axis-still]` builds from the file
    series = to_acceleration(rec)
    case.data = build_input(rec.path, rec, series, [], other_axis_still=still_y)
    return case


@dataclass
class Outcome:
    """What diagnose said about one case, judged against what was hidden."""

    effect: str | None
    seed: int
    named: tuple[str, ...]
    unexplained: bool
    estimates: dict  # the named hidden effect's parameters
    truth: dict
    setup: tuple[str, ...] = ()
    negligible: tuple[str, ...] = ()
    not_physical: tuple[str, ...] = ()
    seconds: float = float("nan")

    @property
    def in_vocabulary(self) -> bool:
        return self.effect in IN_VOCABULARY

    @property
    def found(self) -> bool:
        return self.effect in self.named

    @property
    def wrong(self) -> tuple[str, ...]:
        return tuple(n for n in self.named if n != self.effect)

    @property
    def correct(self) -> bool:
        """The hidden effect named and nothing else; for one outside the vocabulary (and
        for a clean case): nothing named — and for hum, unexplained structure said."""
        if self.effect is None:
            return not self.named
        if not self.in_vocabulary:
            return not self.named and self.unexplained
        return self.found and not self.wrong

    def describe(self) -> str:
        return (f"{self.effect or 'clean'} seed {self.seed} {self.truth}: named {list(self.named)} "
                f"{self.estimates}; unexplained {self.unexplained}; setup {list(self.setup)}; "
                f"negligible {list(self.negligible)}; not physical {list(self.not_physical)}")


def truth_of(case: Case) -> dict:
    """The hidden effect's parameters in diagnose's units (scale: with the part's own)."""
    p = case.params
    e = case.effect
    if e == "scale_factor":
        return {"scale_error_frac": (1 + p["scale"]) * (case.part.s_x / 0.125) - 1}
    conv = {"tilt": ("tilt_coefficient", p.get("kappa")), "cross_axis": ("other_axis_gain", p.get("k")),
            "temperature_offset": ("offset_mg_per_c", 1e3 * p.get("g_per_c", 0)),
            "bandwidth": ("cutoff_hz", p.get("fc_hz")), "nonlinearity": ("quadratic_per_g", p.get("beta")),
            "clipping": ("upper_g", p.get("limit_g")),
            "bias_random_walk": ("random_walk_ug_per_rts", 1e6 * p.get("k_g_per_rts", 0)),
            "reference_delay": ("delay_ms", 1e3 * p.get("delay_s", 0)),
            "sample_loss": ("lost_fraction", p.get("fraction")), "timing": ("hold_back_ms", 1e3 * p.get("hold_s", 0))}
    if e == "vibration":
        return {"frequency_hz": p["f_hz"], "damping_ratio": p["zeta"]}
    if e in conv:
        k, v = conv[e]
        return {k: v}
    return dict(p)


def run_case(effect: str | None, seed: int, settings) -> Outcome:
    """Make, diagnose (told only what a user would tell) and judge one case."""
    import time

    from gateway.core.diagnosis import diagnose

    t0 = time.perf_counter()
    case = make_case(effect, seed)
    result = diagnose(case.data, settings)
    found = {e.name: e for e in result.effects}
    truth = truth_of(case)
    est = {k: float(found[effect].params[k][0]) for k in truth if effect in found and k in found[effect].params}
    return Outcome(effect, seed, tuple(found), result.unexplained, est, truth,
                   tuple(s["name"] for s in result.setup), tuple(n["name"] for n in result.negligible),
                   tuple(n["shape"] for n in result.not_physical), time.perf_counter() - t0)
