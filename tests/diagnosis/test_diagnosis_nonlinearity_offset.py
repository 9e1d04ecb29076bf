"""The nonlinearity is compensated on the motion, not on the offset.

The model fits a + β·a²/g with a the motion's reading; the part's zero-g offset o is the
baseline's. The compensation squared the whole reading, o included: (a + o)² carries
2·o·a, a sensitivity change of 2β·o that the model had given to the scale factor (fitted
beside the nonlinearity and compensated there). Removed twice, it left 2β·o of the travel
— 0.3 % at β = 1.5 %/g and a 0.1 g offset, which a zero-g offset "large part to part"
(the data sheet) and a mount's tilt make ordinary. Found on the own simulator once its
parts as built carry such an offset (docs/diagnosis.md §7).
"""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis.context import G, prepare
from gateway.core.diagnosis.signal_effects import SIGNAL_EFFECTS
from gateway.core.evaluation import summarise_errors
from testing.diagnosis_cases import SENSOR, make_case, run_diagnosis

NONLINEARITY = next(e for e in SIGNAL_EFFECTS if e.name == "nonlinearity")


@pytest.mark.parametrize("offset_g", [-0.1, 0.0, 0.1])
@pytest.mark.parametrize("beta_per_g", [-0.015, 0.01])
def test_the_compensation_inverts_the_quadratic_whatever_the_offset(offset_g, beta_per_g):
    _, data = make_case((), 4)
    prep = prepare(data)
    motion = prep.reading_mps2
    level = offset_g * G + 0.002 * G * prep.drift_shape  # an offset and a drift, as a part has them
    measured = level + motion + beta_per_g * motion**2 / G
    compensated = NONLINEARITY.compensate(prep, np.array([beta_per_g]), measured, None).acc_mps2
    second_order = 3.0 * beta_per_g**2 * np.max(np.abs(motion)) ** 3 / G**2
    assert np.max(np.abs(compensated - level - motion)) <= second_order
    assert second_order < 2.0 * abs(beta_per_g) * 0.1 * np.max(np.abs(motion))  # the old error would show


def _stop_rms_mm(data, track) -> float:
    stops = summarise_errors(data.t_s, track.pos_m, data.ref_pos_m, data.ref_vel_mps).stops
    return float(np.sqrt(np.mean([s.error_m**2 for s in stops]))) * 1e3


OFFSET_G = 0.1


@pytest.mark.parametrize("seed", [3, 4, 5, 6])
def test_a_part_with_a_large_offset_gets_its_distance_back(seed):
    """The bound is the mechanism's own size, not a measured after: the offset squared in
    leaves 2·β·o of the travel (docstring), so a corrected estimate whose stop RMS is
    below half of that over the case's travel has not squared it in. (With the offset
    squared in, seeds 3 and 4 read 0.52 and 0.68 mm against bounds of 0.35 and 0.44 mm.)"""
    part = replace(SENSOR, x=replace(SENSOR.x, zero_g_offset_g=OFFSET_G))
    (term,), data = make_case(("nonlinearity",), seed, part=part)
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["nonlinearity"]
    assert result.effects[0].params["quadratic_per_g"][0] == pytest.approx(term.quadratic_per_g, rel=0.1)
    before, after = (_stop_rms_mm(data, result.distance[k]) for k in ("before", "after"))
    travel_mm = float(np.ptp(data.ref_pos_m)) * 1e3
    squared_offset_error_mm = 2.0 * abs(term.quadratic_per_g) * OFFSET_G * travel_mm
    assert before > squared_offset_error_mm  # the nonlinearity left alone costs more than the bug did
    assert after < 0.5 * squared_offset_error_mm, (after, squared_offset_error_mm)
