"""The part's own output filter is a property of the setup, fitted, not assumed.

A board's CX is within a tolerance (±10–20 %), so its filter sits a few Hz off the nominal
49.7 Hz. Taken as exact, the lag mismatch read as a sensitivity error (Δτ over the short
acceleration phases) and spoiled the cross-validation of a real effect: with a part 10 %
off, a temperature swing was missed. The diagnosis is told the nominal part, as a user is.
"""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.filters import moved_pole, one_pole_lowpass
from testing.diagnosis_cases import SENSOR, make_case, part_within_tolerance, run_diagnosis


def test_moving_the_pole_is_the_filter_at_the_other_bandwidth():
    u = np.random.default_rng(3).normal(size=2000)
    at_50 = one_pole_lowpass(u, 0.002, 50.0)
    np.testing.assert_allclose(moved_pole(at_50, 0.002, 50.0, 42.0), one_pole_lowpass(u, 0.002, 42.0),
                               rtol=0, atol=1e-12)
    assert moved_pole(np.full(10, 3.0), 0.002, 50.0, 60.0) == pytest.approx(np.full(10, 3.0))


@pytest.mark.parametrize("capacitor", [0.9, 1.1])
def test_a_part_off_its_nominal_capacitor_is_measured_and_the_effect_still_named(capacitor):
    part = replace(SENSOR, filter_capacitor_f=SENSOR.filter_capacitor_f * capacitor)
    _, data = make_case(("temperature_offset",), 15, part=part)
    assert data.sensor_bandwidth_hz == SENSOR.bandwidth_hz  # told the nominal part
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["temperature_offset"]
    (setup,) = [s for s in result.setup if s["name"] == "output_filter"]
    assert setup["params"]["bandwidth_hz"][0] == pytest.approx(part.bandwidth_hz, rel=0.03)
    assert "scale_factor" not in [n["name"] for n in result.negligible]


def test_a_part_at_the_edge_of_its_sensitivity_is_judged_with_its_filter_in():
    """Parts as built, clean seed 16: sensitivity −0.96 %, filter 47.9 Hz. The sensitivity
    was accepted first, fitted before the filter was in, and read as −1.04 % ± 0.02 %:
    named as outside the calibration's ±1 %. With every accepted effect in, it is −0.97 %."""
    part = part_within_tolerance(16)
    assert -0.01 < part.x.sensitivity_error_frac < -0.0095  # the case is what it says
    _, data = make_case((), 16, part=part)
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == []
    setup = {s["name"]: s["params"] for s in result.setup}
    assert setup["scale_factor"]["scale_error_frac"][0] == pytest.approx(part.x.sensitivity_error_frac, abs=3e-4)


def test_a_candidate_that_failed_its_cross_validation_is_tried_again_once_the_model_changed():
    """Parts as built, temperature seed 36 (sensitivity +0.36 %): the temperature swing was
    the best candidate in the round after the filter, before the part's sensitivity was in;
    fitted on one half without it, it did not predict the other, and it left the search for
    good. Tried again once the sensitivity is in, it passes and is named."""
    part = part_within_tolerance(36)
    (term,), data = make_case(("temperature_offset",), 36, part=part)
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["temperature_offset"]
    (e,) = result.effects
    assert e.params["offset_mg_per_c"][0] == pytest.approx(term.offset_g_per_c * 1e3, rel=0.05)
