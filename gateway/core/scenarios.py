"""Named motion scenarios for the simulator and the emulated board."""
from __future__ import annotations

from dataclasses import dataclass

from gateway.core.motion_profiles import (
    PiecewiseConstantAcceleration,
    StrokeSettings,
    reciprocating_strokes,
    single_move,
    standstill,
)

SCENARIOS = ("paper", "move", "standstill")


@dataclass(frozen=True)
class ScenarioSettings:
    name: str = "paper"
    strokes: StrokeSettings = StrokeSettings()
    standstill_s: float = 60.0


def build_profile(s: ScenarioSettings) -> PiecewiseConstantAcceleration:
    if s.name == "paper":
        return reciprocating_strokes(s.strokes)
    if s.name == "move":
        st = s.strokes
        return single_move(st.stroke_m, st.max_speed_mps, st.max_acc_mps2, st.rest_start_s, st.rest_end_s,
                           st.jerk_mps3)
    if s.name == "standstill":
        if not s.standstill_s > 0:
            raise ValueError("a standstill needs a positive duration")
        return standstill(s.standstill_s)
    raise ValueError(f"unknown scenario {s.name!r} (known: {', '.join(SCENARIOS)})")
