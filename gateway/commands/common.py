"""Argument types and scenario options shared by several subcommands."""
from __future__ import annotations

import argparse
import math
import signal

from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import SCENARIOS, ScenarioSettings


def _checked(text: str, convert, what: str, ok, requirement: str):
    """Parse a command-line number; argparse turns the error into a usage line, exit 2."""
    try:
        value = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if not ok(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be {requirement}")
    return value


def positive_float(text: str) -> float:
    return _checked(text, float, "a number", lambda v: math.isfinite(v) and v > 0, "a positive number")


def non_negative_float(text: str) -> float:
    return _checked(text, float, "a number", lambda v: math.isfinite(v) and v >= 0, "a number ≥ 0")


def positive_int(text: str) -> int:
    return _checked(text, int, "a whole number", lambda v: v >= 1, "at least 1")


def seed_int(text: str) -> int:
    return _checked(text, int, "a whole number", lambda v: v >= 0, "≥ 0")


def add_scenario_options(p: argparse.ArgumentParser, default_strokes: int = 10) -> None:
    d = StrokeSettings()
    g = p.add_argument_group("scenario (defaults: the paper's experiment)")
    g.add_argument("--scenario", choices=SCENARIOS, default="paper",
                   help="paper: reciprocating strokes; move: one move; standstill: at rest (default: paper)")
    g.add_argument("--strokes", type=positive_int, default=default_strokes,
                   help=f"one-way strokes, each followed by a stop (default: {default_strokes})")
    g.add_argument("--stroke-m", type=positive_float, default=d.stroke_m,
                   help=f"stroke length, m (default: {d.stroke_m})")
    g.add_argument("--speed-mps", type=positive_float, default=d.max_speed_mps,
                   help=f"cruise speed, m/s (default: {d.max_speed_mps})")
    g.add_argument("--acc-mps2", type=positive_float, default=d.max_acc_mps2,
                   help=f"acceleration, m/s² (default: {d.max_acc_mps2})")
    g.add_argument("--dwell-s", type=non_negative_float, default=d.dwell_s,
                   help=f"stop at each end, s (default: {d.dwell_s})")
    g.add_argument("--rest-s", type=non_negative_float, default=d.rest_start_s,
                   help=f"rest before the first stroke, s (default: {d.rest_start_s})")
    g.add_argument("--jerk-mps3", type=non_negative_float, default=d.jerk_mps3,
                   help="jerk limit of the drive, m/s³: each acceleration step becomes a ramp (an S-curve drive, "
                        "as servo drives and robots move; e.g. 400); 0: steps, the paper's drive (default: 0)")
    g.add_argument("--duration", type=positive_float, default=60.0, dest="standstill_s",
                   help="length of the standstill scenario, s (default: 60)")
    g.add_argument("--seed", type=seed_int, default=0, help="random seed (default: 0)")


def scenario_from_args(args: argparse.Namespace) -> ScenarioSettings:
    strokes = StrokeSettings(
        stroke_m=args.stroke_m,
        max_speed_mps=args.speed_mps,
        max_acc_mps2=args.acc_mps2,
        strokes=args.strokes,
        dwell_s=args.dwell_s,
        rest_start_s=args.rest_s,
        jerk_mps3=args.jerk_mps3,
    )
    return ScenarioSettings(name=args.scenario, strokes=strokes, standstill_s=args.standstill_s)


class StopOnSignal:
    """A flag that SIGTERM and SIGINT raise: long-running commands end their loop cleanly."""

    def __init__(self) -> None:
        self.stop = False
        signal.signal(signal.SIGTERM, self._raise)
        signal.signal(signal.SIGINT, self._raise)

    def _raise(self, _signum, frame) -> None:
        self.stop = True

    def __bool__(self) -> bool:
        return self.stop
