"""A USB latency timer matters by the position a host-stamped sample carries, not by a
residual share.

Both timing models — the baseline's Exp(μ) and the extension's U(0, L) + Exp(μ) — are
distributions of the same delays around their own means, so the spread each leaves is
the same and the share it "explains" is ~0 for any L. The effect used to be named only
when integrating on host times happened to move the distance by 0.5 mm, which the
paper's acceleration steps do and a gentler machine does not (found on the simulator
with gentle strokes: a 4.5 ms latency timer left "negligible"). What a latency timer
costs a user is v·δt on every host-stamped sample (side_effects.host_time_position_mm).
"""
from dataclasses import replace
import math

import numpy as np
import pytest

from gateway.core.diagnosis.judgement import MIN_DISTANCE_GAIN_MM, matters
from gateway.core.diagnosis.side_effects import BASELINE_LATENCY_MEAN_S, host_time_position_mm
from gateway.core.motion_profiles import StrokeSettings
from tests.diagnosis_cases import STROKES, make_case, run_diagnosis


def test_the_position_is_the_top_speed_times_the_delay_scatter_beyond_the_baseline_link():
    rng = np.random.default_rng(5)
    hold_s = 0.008
    delay = rng.uniform(0.0, hold_s, 200_000)
    speed = np.abs(np.sin(np.linspace(0.0, 20.0, delay.size)))  # top speed 1 m/s
    expected = 0.99 * math.sqrt(hold_s**2 / 12 - BASELINE_LATENCY_MEAN_S**2) * 1e3
    assert host_time_position_mm(delay, speed) == pytest.approx(expected, rel=0.02)
    # the baseline link's own jitter is no effect at all
    assert host_time_position_mm(rng.exponential(BASELINE_LATENCY_MEAN_S, 200_000), speed) < 0.05
    assert host_time_position_mm(delay, np.zeros_like(delay)) == 0.0


def test_matters_takes_the_position_where_neither_share_nor_distance_can_say():
    assert matters(None, 0.1, MIN_DISTANCE_GAIN_MM * 1.2)[0]
    named, why = matters(None, 0.1, MIN_DISTANCE_GAIN_MM * 0.5)
    assert not named and "host-timed position" in why
    # a loss of distance still vetoes
    assert not matters(None, -2.0, 5.0)[0]


@pytest.mark.slow
def test_a_latency_timer_on_a_gentle_machine_is_named_by_what_it_does_to_positions():
    gentle = StrokeSettings(strokes=STROKES, max_speed_mps=0.5, max_acc_mps2=2.0)
    named, small_distance = [], 0
    for seed in range(6):
        _, data = make_case(("timing",), seed, strokes=gentle)
        result = run_diagnosis(data)
        named.append(tuple(e.name for e in result.effects))
        timing = [e for e in result.effects if e.name == "timing"]
        if timing and timing[0].gain["distance"].get("improvement_mm", 1.0) < MIN_DISTANCE_GAIN_MM:
            small_distance += 1
    assert named == [("timing",)] * 6, named
    # the old rule (share or distance) would have left these negligible
    assert small_distance >= 1


@pytest.mark.slow
def test_on_a_slow_machine_the_timer_is_named_only_where_the_distance_needs_it():
    # 0.15 m/s (a robot's cruise) with a 4 ms timer: 0.15 × 4/√12 ≈ 0.17 mm per host-stamped
    # position, under the threshold; over seconds of motion the host-timed integration can
    # still move the distance by more (then it is named for that)
    slow = StrokeSettings(strokes=STROKES, max_speed_mps=0.15, max_acc_mps2=1.0)
    expected = 0.15 * math.sqrt(0.004**2 / 12 - BASELINE_LATENCY_MEAN_S**2) * 1e3
    outcomes = set()
    for seed in range(3, 8):
        _, data = make_case(("timing",), seed, adjust=lambda t: replace(t, hold_s=0.004), strokes=slow)
        result = run_diagnosis(data)
        named = [e for e in result.effects if e.name == "timing"]
        if named:
            assert named[0].gain["position_mm"] == pytest.approx(expected, rel=0.25)
            assert named[0].gain["distance"]["improvement_mm"] >= MIN_DISTANCE_GAIN_MM
            outcomes.add("named")
        else:
            (entry,) = [n for n in result.negligible if n["name"] == "timing"]
            assert entry["position_mm"] == pytest.approx(expected, rel=0.25)
            assert "host-timed position off by" in entry["why"]
            outcomes.add("negligible")
        assert [e.name for e in result.effects] in ([], ["timing"])
    assert outcomes == {"named", "negligible"}, outcomes
