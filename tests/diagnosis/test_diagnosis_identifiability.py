"""What one record cannot tell apart is said, not decided (identifiability.py)."""
import numpy as np

from gateway.core.diagnosis.context import prepare
from gateway.core.diagnosis.identifiability import temperature_in_line_with_drift, what_separates
from testing.diagnosis_cases import make_case, run_diagnosis


def test_a_temperature_that_runs_in_line_with_time_cannot_be_told_from_the_drift():
    _, data = make_case((), 9200)
    t = data.t_s - data.t_s[0]
    data.temp_c = np.round(25.0 + 0.3 * t, 2)  # a steady warm-up: all of it offset + drift
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == []
    (temp,) = [c for c in result.candidates if c.name == "temperature_offset"]
    assert temp.not_separable_from == ["drift"]
    assert any("temperature and drift cannot be told apart" in c for c in result.cannot)
    assert "temperature swing" in what_separates("temperature_offset", "drift")


def test_a_temperature_swing_within_the_record_can_be():
    _, data = make_case(("temperature_offset",), 9201)
    prep = prepare(data)
    assert temperature_in_line_with_drift(prep, 1e-3) is None


def test_named_effects_carry_the_list_even_when_it_is_empty():
    _, data = make_case(("scale_factor",), 9202)
    result = run_diagnosis(data)
    doc = result.to_dict()
    assert [e["name"] for e in doc["effects"]] == ["scale_factor"]
    assert doc["effects"][0]["not_separable_from"] == []
