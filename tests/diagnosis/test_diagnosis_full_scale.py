"""The part's saturation is read through its own sensitivity.

The part saturates in acceleration, at its ±2 g range; the duty cycle of that saturation
passes through the part's sensitivity like any other reading, so a part 0.7 % low reads
its full scale as ±1.986 g. The baseline clipped its model at ±2 g whatever the fitted
sensitivity, and a vibration ringing past full scale then had `clipping` named beside it
at ±1.986 g (the own simulator's vibration seed 8, parts as built; docs/diagnosis.md §7).
"""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis.context import G, prepare
from gateway.core.diagnosis.model_fit import predict
from gateway.core.diagnosis.signal_effects import SIGNAL_EFFECTS
from testing.diagnosis_cases import SENSOR, make_case, run_diagnosis

SCALE = next(e for e in SIGNAL_EFFECTS if e.name == "scale_factor")


def _part(sensitivity_error_frac: float):
    return replace(SENSOR, x=replace(SENSOR.x, sensitivity_error_frac=sensitivity_error_frac))


@pytest.mark.parametrize("sensitivity_error_frac", [-0.008, 0.006])
def test_a_vibration_past_full_scale_on_a_part_off_its_sensitivity_names_no_clipping(sensitivity_error_frac):
    part = _part(sensitivity_error_frac)
    _, data = make_case(("vibration",), 8, part=part)
    full_scale_g = 2.0 * (1.0 + sensitivity_error_frac)
    acc_g = np.abs(data.acc_mps2[data.valid]) / G
    assert np.count_nonzero(acc_g > full_scale_g - 0.003) >= 10  # the case saturates, as it says
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["vibration"]
    assert "clipping" not in [n["name"] for n in result.negligible]
    (setup,) = [s for s in result.setup if s["name"] == "scale_factor"]
    assert setup["params"]["scale_error_frac"][0] == pytest.approx(sensitivity_error_frac, abs=1e-3)


def test_the_model_saturates_at_full_scale_times_the_sensitivity():
    _, data = make_case((), 8)
    prep = prepare(data)
    pushed_past_full_scale = [3.0 * G, 0.0]  # an offset that drives every sample into saturation
    for s in (-0.008, 0.0, 0.006):
        modelled = predict(prep, (SCALE,), np.array(pushed_past_full_scale + [s]))
        assert np.max(modelled) == pytest.approx(2.0 * G * (1.0 + s), rel=1e-12)
    assert np.max(predict(prep, (), np.array(pushed_past_full_scale))) == pytest.approx(2.0 * G, rel=1e-12)
