"""A USB latency timer matters by how far it misplaces a host-stamped sample, not by a
residual share.

Both timing models — the baseline's Exp(μ) and the extension's U(0, L) + Exp(μ) — are
distributions of the same delays around their own means, so the spread each leaves is
the same and the share it "explains" is ~0 for any L. What a latency timer costs a user
is v·δt on every host-stamped sample (side_effects.host_time_position_mm, reported); it
is named when the delays scatter by more than the board's own timing convention allows
(half a sample period: judgement.HOST_SCATTER_PERIODS), at any speed.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis.judgement import HOST_SCATTER_PERIODS
from gateway.core.diagnosis.side_effects import BASELINE_LATENCY_MEAN_S, host_time_position_mm
from gateway.core.motion_profiles import StrokeSettings
from testing.diagnosis_cases import STROKES, make_case, run_diagnosis


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


@pytest.mark.slow
def test_a_latency_timer_on_a_gentle_machine_is_named():
    gentle = StrokeSettings(strokes=STROKES, max_speed_mps=0.5, max_acc_mps2=2.0)
    named = []
    for seed in range(6):
        _, data = make_case(("timing",), seed, strokes=gentle)
        result = run_diagnosis(data)
        named.append(tuple(e.name for e in result.effects))
    assert named == [("timing",)] * 6, named


@pytest.mark.slow
@pytest.mark.parametrize("hold_s, named", [(0.004, True), (0.0015, False)])
def test_a_timer_is_named_when_its_scatter_exceeds_half_a_period(hold_s, named):
    # 500 samples/s: a 4 ms timer scatters by 4/√12 = 1.15 ms = 0.58 of a period, a
    # 1.5 ms one by 0.43 ms = 0.22 of a period (the board's timing convention allows 0.5)
    slow = StrokeSettings(strokes=STROKES, max_speed_mps=0.15, max_acc_mps2=1.0)
    for seed in range(3, 6):
        _, data = make_case(("timing",), seed, strokes=slow, adjust=lambda t: replace(
            t, latency_timer_s=hold_s, clock_step_s=0.0, clock_rate_error=0.0))
        result = run_diagnosis(data)
        timing = [e for e in result.effects if e.name == "timing"]
        if named:
            assert timing, [c.__dict__ for c in result.candidates if c.name == "timing"]
            assert timing[0].gain["host_scatter_periods"] > HOST_SCATTER_PERIODS
        else:
            assert not timing
            entries = [n for n in result.negligible if n["name"] == "timing"]
            assert all("scatter" in n["why"] for n in entries)
        assert [e.name for e in result.effects] in ([], ["timing"])
