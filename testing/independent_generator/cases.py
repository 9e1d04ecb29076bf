"""Recordings with one hidden effect (or none), made by the independent generator.

    case = make_case("vibration", seed)             # the cause is drawn here...
    result = diagnose(case.data, settings)          # ...diagnose gets the recording only
    outcome = run_case("vibration", seed, settings) # both, judged

A case: 6 strokes of 30 cm on x (S-curves, 1 m/s, 10 m/s², 400 m/s³) with rests of
0.6–1 s, while the other axis (y) makes 3–5 moves of its own that overlap them — both axes
move, and nothing tells diagnose otherwise. For bias_random_walk a 60 s standstill; for
temperature_offset the machine works in three bursts of four strokes with 8–12 s pauses
(its duty is what heats the board). Part, noise, link and cause parameters come from
numpy.random.default_rng([seed, STREAM]).

Every cause is made the way it works (physics.py), from the data sheet and board facts
in /work/shared/spec and textbook physics, written before any diagnosis ran on this
version (the design was frozen, then run once on new seeds: docs/diagnosis.md §7):

- every part: zero-g offset, sensitivity within its calibration (1 %), CX within 10 %,
  RSET within 1 %, a zero-g temperature coefficient within ±0.5 mg/°C and the paper's
  exponential zero drift; the board's temperature creeps by 0.1–0.4 °C over a record;
- CAUSES below, one per case; "hum" is outside the diagnosis's vocabulary: the right
  answer is "unexplained structure", no name.

The raw recording goes through gateway.offline.recording.to_acceleration exactly as a file
would. This package never imports gateway.core.simulator, sensor_effects or
motion_profiles, nor the diagnosis's candidates (tests/diagnosis/test_diagnosis_independent.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gateway.commands.diagnose import build_input
from gateway.offline.recording import Recording, to_acceleration
from testing.independent_generator import board, physics
from testing.independent_generator.motion import MotionPlan, MoveLimits, strokes

STREAM = 15  # this design's random stream (the earlier generator drew from 14)
STROKES = 6
STANDSTILL_S = 60.0
# name the diagnosis should give → the cause as made (physics.py), sizes drawn uniformly
CAUSES = {
    "scale_factor": "sensitivity ±2–5 % beyond the calibration (the part's own within 1 %)",
    "tilt": "a rail of cubic height: pitch κ1·x + κ2·x², |κ1| 0.03–0.09 rad/m, |κ2·0.3 m| ≤ 30 % of κ1",
    "temperature_offset": "board heated by the drive's duty (τ 8–20 s, 3–6 °C above ambient at a burst's mean "
                          "duty held), die lagging 1–3 s, ±0.5–2 mg/°C",
    "vibration": "sensor on a cantilever bracket, f1 15–45 Hz (f2 = 6.27·f1), ζ 0.02–0.08, base-excited by "
                 "the motion and by the drive's random vibration (0.03–0.1 g rms, 5–400 Hz) while moving",
    "cross_talk": "x reads c·a_y (misalignment ±1–3° plus cross-axis ±2 %, |c| 0.02–0.07) while both move",
    "bandwidth": "a wrong CX fitted: 0.22, 0.33 or 0.47 µF (E6) for 0.1 µF",
    "nonlinearity": "modulator deviation: quadratic ±0.5–1.5 %/g, cubic up to ±0.5 %/g²",
    "clipping": "output stage saturating softly (10 mg knee) at +0.6–0.9 g, the lower limit 0.9–1.1× as far",
    "bias_random_walk": "zero-g wander, 1/f^α with α 1.5–2, 2–6 mg rms change over 60 s (standstill)",
    "reference_delay": "the reference is the command and the axis follows through its position loop "
                       "(lag 5–15 ms, ζ 0.7), or the logger stamps the encoder 5–15 ms late",
    "sample_loss": "0.3–1.5 % of frames lost in bursts (geometric, mean 2)",
    "timing": "a buffering USB adapter (62-byte packets, latency timer 4–16 ms), bursts stamped at once, "
              "an NTP step back of 5–30 ms in half of the cases",
    "hum": "supply ripple 50 Hz ± 0.1 Hz, 4–10 mg, third harmonic 10–30 % (outside the vocabulary)",
}
EFFECT_SIZES = CAUSES  # the name the benchmark reads
IN_VOCABULARY = tuple(n for n in CAUSES if n != "hum")


def _signed(rng, lo, hi):
    return float(rng.uniform(lo, hi) * rng.choice((-1.0, 1.0)))


def draw(name: str | None, rng: np.random.Generator) -> dict:
    """The hidden cause's parameters (empty for a clean case)."""
    if name is None:
        return {}
    d = {
        "scale_factor": lambda: {"scale": _signed(rng, 0.02, 0.05)},
        "tilt": lambda: (lambda k1: {"kappa1": k1, "kappa2": k1 / 0.3 * rng.uniform(-0.3, 0.3)})(
            _signed(rng, 0.03, 0.09)),
        "temperature_offset": lambda: {"g_per_c": _signed(rng, 0.5e-3, 2e-3), "tau_s": rng.uniform(8, 20),
                                       "rise_c": rng.uniform(3, 6), "die_lag_s": rng.uniform(1, 3)},
        "vibration": lambda: {"f_hz": rng.uniform(15, 45), "zeta": rng.uniform(0.02, 0.08),
                              "drive_rms_g": rng.uniform(0.03, 0.1)},
        "cross_talk": lambda: {"c": (math.sin(math.radians(_signed(rng, 1, 3))) + rng.uniform(-0.02, 0.02))},
        "bandwidth": lambda: {"cx_f": float(rng.choice((0.22e-6, 0.33e-6, 0.47e-6)))},
        "nonlinearity": lambda: {"beta2": _signed(rng, 0.005, 0.015), "beta3": rng.uniform(-0.005, 0.005)},
        "clipping": lambda: {"upper_g": rng.uniform(0.6, 0.9), "lower_ratio": rng.uniform(0.9, 1.1)},
        "bias_random_walk": lambda: {"alpha": rng.uniform(1.5, 2.0), "change_rms_g": rng.uniform(2e-3, 6e-3)},
        "reference_delay": lambda: {"lag_s": rng.uniform(5e-3, 15e-3), "servo": float(rng.random() < 0.5)},
        "sample_loss": lambda: {"fraction": rng.uniform(0.003, 0.015)},
        "timing": lambda: {"latency_timer_s": rng.uniform(4e-3, 16e-3),
                           "ntp_step_s": float(rng.uniform(5e-3, 30e-3) if rng.random() < 0.5 else 0.0)},
        "hum": lambda: {"amp_g": rng.uniform(4e-3, 10e-3), "f_hz": rng.uniform(49.9, 50.1),
                        "third": rng.uniform(0.1, 0.3), "phase": rng.uniform(0, 2 * math.pi)},
    }
    if name not in d:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(CAUSES)}")
    params = {k: float(v) for k, v in d[name]().items()}
    if name == "cross_talk":
        # |c| at least 0.02: a smaller draw is pushed out, keeping its sign
        params["c"] = math.copysign(min(max(abs(params["c"]), 0.02), 0.07), params["c"])
    return params


def _other_axis_plan(rng, end_s: float) -> MotionPlan:
    """3–5 moves of 10–30 cm at random times: they overlap the x strokes."""
    plan = MotionPlan(MoveLimits(), [])
    n = int(rng.integers(3, 6))
    starts = np.sort(rng.uniform(0.5, max(1.0, end_s - 1.5), n))
    t_free = 0.0
    for s in starts:
        s = max(s, t_free + 0.1)
        plan.moves.append((float(s), _signed(rng, 0.1, 0.3)))
        t_free = plan.end_s()
    return plan


def _bursts(rng, bursts: int = 3, per_burst: int = 4) -> MotionPlan:
    """The machine's duty: bursts of strokes with pauses of 8–12 s between them."""
    plan = MotionPlan(MoveLimits(), [])
    t = 1.0
    for _ in range(bursts):
        for k in range(per_burst):
            plan.moves.append((t, 0.3 if k % 2 == 0 else -0.3))
            t = plan.end_s() + float(rng.uniform(0.6, 1.0))
        t = plan.end_s() + float(rng.uniform(8.0, 12.0))
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
    if effect == "bandwidth":
        part.cx_f = params["cx_f"] * (1 + rng.uniform(-0.10, 0.10))
    offset_g_per_c = rng.uniform(-0.5e-3, 0.5e-3) + params.get("g_per_c", 0.0)
    if effect == "bias_random_walk":
        x_plan = MotionPlan(MoveLimits(), [])
        duration = STANDSTILL_S
    elif effect == "temperature_offset":
        x_plan = _bursts(rng)
        duration = x_plan.end_s() + 5.0  # and it cools at rest
    else:
        x_plan = strokes(rng, STROKES)
        duration = x_plan.end_s() + 1.0
    still_y = effect == "bias_random_walk"
    y_plan = MotionPlan(MoveLimits(), []) if still_y else _other_axis_plan(rng, duration)

    rise = board.periods(part, duration, rng)
    t_fine = np.arange(0.0, rise[-1] + 0.01, 1.0 / board.FINE_HZ)
    # the reference is the controller's command; the axis follows it (or the logger is late)
    cmd_pos, cmd_vel, cmd_acc = x_plan.evaluate(t_fine)
    x_pos, x_vel, x_acc = cmd_pos, cmd_vel, cmd_acc
    if effect == "reference_delay" and params["servo"]:
        x_pos = physics.servo_follow(cmd_pos, params["lag_s"])
        x_vel = np.gradient(x_pos) * board.FINE_HZ
        x_acc = np.gradient(x_vel) * board.FINE_HZ
    _, _, y_acc = y_plan.evaluate(t_fine)
    ax_g, ay_g = x_acc / board.G, y_acc / board.G

    # what reaches each sense element, in g
    if effect == "vibration":
        moving = np.abs(x_vel) > 0.01
        base = ax_g + physics.drive_vibration(moving, params["drive_rms_g"], rng)
        ax_g = physics.cantilever_tip(base, params["f_hz"], params["zeta"])
    if effect == "tilt":
        ax_g = ax_g + np.sin(physics.rail_pitch_rad(x_pos, params["kappa1"], params["kappa2"]))
    if effect == "cross_talk":
        ax_g, ay_g = ax_g + params["c"] * ay_g, ay_g - params["c"] * ax_g
    # temperature: the board's sensor, and the die lagging it
    if effect == "temperature_offset":
        heat = physics.machine_heat(x_acc, x_vel)
        mean_heat = float(np.mean(heat[(t_fine > 1.0) & (t_fine < 1.0 + 4 * 1.5)])) or 1.0
        board_c = 25.0 + physics.first_order(heat / mean_heat * params["rise_c"], params["tau_s"], 0.0)
        die_c = physics.first_order(board_c, params["die_lag_s"], 25.0)
    else:
        board_c = 25.0 + rng.uniform(0.1, 0.4) * t_fine / t_fine[-1]
        die_c = board_c
    ax_g = ax_g + offset_g_per_c * (die_c - 25.0)
    if effect == "bias_random_walk":
        ax_g = ax_g + physics.power_law_wander(t_fine.size, params["alpha"], params["change_rms_g"],
                                               STANDSTILL_S / 2, rng)
    # the paper's zero drift, C1·(1 − e^(−t/T)) with T of 20–40 min
    ax_g = ax_g + _signed(rng, 5e-3, 20e-3) * (1 - np.exp(-t_fine / rng.uniform(1200, 2400)))
    if effect == "nonlinearity":
        ax_g = ax_g + params["beta2"] * ax_g**2 + params["beta3"] * ax_g**3

    fc = part.bandwidth_hz
    yx = board.rc_lowpass(ax_g + board.element_noise(t_fine.size, rng), fc, board.FINE_HZ)
    yy = board.rc_lowpass(ay_g + board.element_noise(t_fine.size, rng), fc, board.FINE_HZ)
    if effect == "clipping":
        yx = physics.soft_saturation(yx, params["upper_g"], -params["upper_g"] * params["lower_ratio"], 0.01)
    if effect == "hum":
        yx = yx + physics.mains_ripple(t_fine, params["amp_g"], params["f_hz"], params["third"], params["phase"])
    s_x = part.s_x * (1.0 + params.get("scale", 0.0))
    fall_x = board.duty_cycles(t_fine, yx, rise, part.d0_x, s_x)
    fall_y = board.duty_cycles(t_fine, yy, rise, part.d0_y, part.s_y)
    t1x, t1y, t2 = board.capture(rise, fall_x, fall_y, part.tick_phase)
    n = t2.size
    if effect == "timing":
        host = physics.usb_adapter_arrivals(rise[1:], params["latency_timer_s"], rng, params["ntp_step_s"])
    else:
        host = board.host_arrivals(rise[1:], rng)
    seq = np.arange(n) % 65536
    keep = np.ones(n, dtype=bool)
    if effect == "sample_loss":
        lost_target = int(round(params["fraction"] * n))
        while (~keep).sum() < lost_target:
            k = int(rng.integers(10, n - 10))
            keep[k:k + int(rng.geometric(0.5))] = False
    # the reference at each period's start (board time from the first sample on)
    start = rise[:-1] - rise[0]
    ref_at = start + rise[0]
    if effect == "reference_delay" and not params["servo"]:
        ref_at = ref_at - params["lag_s"]  # stamped late: the value logged at t is from t − lag
    rp, rv, ra = x_plan.evaluate(ref_at)
    # the STATUS temperature: once per second, 0.01 °C, from the board's sensor
    t_status = np.floor(start)
    temp_col = np.round(np.interp(t_status + rise[0], t_fine, board_c), 2)
    cols = {"seq": seq, "t1x": t1x, "t1y": t1y, "t2": t2, "flags": np.zeros(n), "t_host_s": host,
            "temp_c": temp_col, "ref_pos_m": rp, "ref_vel_mps": rv, "ref_acc_mps2": ra}
    cols = {k: np.asarray(v, dtype=float)[keep] for k, v in cols.items()}
    rec = Recording(f"<independent seed {seed}>", {"tick_hz": str(board.TICK_HZ), "source": "independent"},
                    cols, "raw")
    case = Case(effect, seed, params, part, still_y, rec)
    # exactly what `adxlgw diagnose FILE.csv` builds from the file (nothing else told)
    series = to_acceleration(rec)
    case.data = build_input(rec.path, rec, series, [], other_axis_still=False)
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
    not_separable: dict = field(default_factory=dict)  # named → its not_separable_from
    error: str = ""  # the diagnosis raised: its exception, one line

    @property
    def found_in_set(self) -> bool:
        """Named, or in the set of causes a named effect cannot be told from here."""
        return self.found or any(self.effect in s for s in self.not_separable.values())

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
    """The hidden cause's parameters under the names and units diagnose reports them in
    (EffectResult.params), where the physical parameter is the quantity diagnose
    reports; the others are judged by name."""
    p, e = case.params, case.effect
    if e == "scale_factor":
        return {"scale_error_frac": (1 + p["scale"]) * (case.part.s_x / 0.125) - 1}
    if e == "vibration":
        return {"frequency_hz": p["f_hz"], "damping_ratio": p["zeta"]}
    same = {"tilt": ("tilt_coefficient", p.get("kappa1")),
            "temperature_offset": ("offset_mg_per_c", 1e3 * p.get("g_per_c", 0.0)),
            "cross_talk": ("gain", p.get("c")),
            "nonlinearity": ("quadratic_per_g", p.get("beta2")),
            "clipping": ("upper_g", p.get("upper_g")),
            # the motion at t is the reference at t + d: a command leads the servo's motion
            # (d = −lag); a late-stamped encoder lags it (d = +lag)
            "reference_delay": ("delay_ms", 1e3 * p.get("lag_s", 0.0) * (-1.0 if p.get("servo") else 1.0)),
            "sample_loss": ("lost_fraction", p.get("fraction"))}
    if e in same:
        key, value = same[e]
        return {key: value}
    return {}


def run_case(effect: str | None, seed: int, settings) -> Outcome:
    """Make, diagnose (told only what a user would tell) and judge one case. A diagnosis
    that raises is an outcome too (error), never a lost case."""
    import time

    from gateway.core.diagnosis import diagnose

    t0 = time.perf_counter()
    case = make_case(effect, seed)
    truth = truth_of(case)
    try:
        result = diagnose(case.data, settings)
    except Exception as err:  # noqa: BLE001 — counted and reported, the run goes on
        return Outcome(effect, seed, (), False, {}, truth, seconds=time.perf_counter() - t0,
                       error=f"{type(err).__name__}: {err}")
    found = {e.name: e for e in result.effects}
    est = {k: float(found[effect].params[k][0]) for k in truth if effect in found and k in found[effect].params}
    return Outcome(effect, seed, tuple(found), result.unexplained, est, truth,
                   tuple(s["name"] for s in result.setup), tuple(n["name"] for n in result.negligible),
                   tuple(n["shape"] for n in result.not_physical), time.perf_counter() - t0,
                   {e.name: tuple(e.not_separable_from) for e in result.effects})
