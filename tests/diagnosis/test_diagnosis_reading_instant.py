"""Where in its period the modulator reads the signal is a property of the setup, fitted.

The data sheet does not say whether the ADXL202's duty cycle reads the filtered signal over
its period or where the duty cycle ends (natural sampling); the baseline takes the period's
mean. An edge-read board's recording carries (S·T2/2g)·d(a²)/dt more: the diagnosis
measures the fraction (0: mean, 1: edge) and reports it with the setup's properties, never
as an effect (signal_effects.ReadingInstant). Seeds of the tests' own range (9000+).
"""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis import list_effects
from testing.diagnosis_cases import SENSOR, make_case, run_diagnosis


def _reading_instant(result):
    found = [s for s in result.setup if s["name"] == "reading_instant"]
    return found[0]["params"]["edge_fraction"][0] if found else None


@pytest.mark.parametrize("seed", [9101, 9102])
def test_an_edge_reading_board_is_measured_as_one_and_nothing_is_named(seed):
    _, data = make_case((), seed, part=replace(SENSOR, dcm_reading="edge"))
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == []
    assert _reading_instant(result) == pytest.approx(1.0, abs=0.15)
    assert "reading_instant" not in [name for name, _ in list_effects()]  # never an effect to name


def test_a_period_mean_board_is_not_taken_for_an_edge_reader():
    _, data = make_case((), 9101)
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == []
    fraction = _reading_instant(result)
    assert fraction is None or fraction < 0.15


def test_a_hidden_effect_is_still_named_on_an_edge_reading_board():
    _, data = make_case(("nonlinearity",), 9103, part=replace(SENSOR, dcm_reading="edge"))
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["nonlinearity"]
    assert _reading_instant(result) == pytest.approx(1.0, abs=0.15)
    assert np.isfinite(result.effects[0].params["quadratic_per_g"][0])
