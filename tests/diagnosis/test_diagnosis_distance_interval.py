"""A distance loss counts when it lies beyond its interval, at any number of stops.

The distance gain compares the smoothed estimate's error at the reference's stops before
and after an effect's compensation; its interval is a bootstrap over the stops
(`judgement.distance_interval`). A right compensation whose effect had happened to
cancel other errors at a few stops makes a "loss" whose interval reaches above zero; a
compensation that moves the estimate away from the reference makes one beyond it. With
one stop, or only the final position, the interval is that one value: any loss counts
(the old rule's statistic could not exceed √n, so with 4 stops or fewer no loss counted).
"""
from __future__ import annotations

import numpy as np
import pytest

from gateway.core.diagnosis.judgement import HOST_SCATTER_PERIODS, distance_interval, matters
from testing.diagnosis_cases import run_case


def gain(before_mm, after_mm, metric="stop_rms_mm"):
    b, a = np.asarray(before_mm, float), np.asarray(after_mm, float)
    rms = lambda x: float(np.sqrt(np.mean(x**2)))  # noqa: E731
    return {"available": True, "metric": metric,
            "before": {"stop_rms_mm": rms(b), "final_mm": float(b[-1]), "stops_mm": b.tolist()},
            "after": {"stop_rms_mm": rms(a), "final_mm": float(a[-1]), "stops_mm": a.tolist()},
            "improvement_mm": rms(b) - rms(a) if metric == "stop_rms_mm" else abs(b[-1]) - abs(a[-1])}


def test_a_loss_whose_interval_reaches_zero_does_not_count():
    # one stop much worse, the others better: the bootstrap interval straddles zero
    g = gain([1.05, -1.31, 1.62, 1.04, 2.0, -1.5], [0.2, 0.3, 0.1, 0.2, 4.5, 0.2])
    lo, hi = distance_interval(g)
    assert g["improvement_mm"] < 0 and lo < 0 < hi
    assert matters(g)[0]


@pytest.mark.parametrize("seed", range(5))
def test_a_compensation_that_moves_the_estimate_away_is_beyond_its_interval(seed):
    rng = np.random.default_rng(seed)
    other = rng.normal(0.0, 1.0, 6)  # mm, every other error at six stops
    added = rng.choice((-1.0, 1.0), 6) * rng.uniform(2.0, 4.0, 6)  # a fudge term's compensation
    g = gain(other, other + added)
    assert distance_interval(g)[1] < 0
    named, why = matters(g)
    assert not named and "worse by" in why


@pytest.mark.parametrize("stops", [1, 2, 4])
def test_a_loss_counts_at_any_number_of_stops(stops):
    g = gain([1.0] * stops, [10_000.0] * stops)  # a 10 m loss
    assert not matters(g)[0]
    g = gain([1.0, -1.0], [2.0, 3.0], metric="final_mm")
    assert distance_interval(g) == (g["improvement_mm"], g["improvement_mm"])
    assert not matters(g)[0]


def test_the_interval_is_seeded_and_reported():
    g = gain([1.0, -2.0, 0.5, 3.0], [0.5, -1.0, 0.4, 1.0])
    assert distance_interval(g) == distance_interval(g)
    lo, hi = distance_interval(g)
    assert lo <= g["improvement_mm"] <= hi
    assert distance_interval({"available": False}) is None


def test_host_timing_and_leftover_structure_decide_too():
    assert not matters(None, HOST_SCATTER_PERIODS * 0.5)[0]
    assert matters(None, HOST_SCATTER_PERIODS * 2)[0]
    named, why = matters(None, None, "a spectral line at 31.7 Hz")
    assert not named and "31.7 Hz" in why


@pytest.mark.slow
def test_the_simulators_temperature_case_whose_compensation_is_right_is_named():
    # parts as built, S-curve, readings at the edge: fitted −0.78 mg/°C against −0.74,
    # "worse by 0.62 mm" over 4 stops — within its interval
    out = run_case(("temperature_offset",), 17, parts_within_tolerance=True, jerk_mps3=400.0,
                   dcm_reading="edge")
    assert out.named == ("temperature_offset",), out.describe()
