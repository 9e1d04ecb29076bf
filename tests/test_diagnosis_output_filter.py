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
from tests.diagnosis_cases import SENSOR, make_case, run_diagnosis


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
