"""The extended model a diagnosis writes, applied by `adxlgw estimate --model`: written once
(gateway/core/model_compensation.py), the same corrections the diagnosis measures."""
import json

import numpy as np
import pytest

from gateway.cli import main
from gateway.core.model_compensation import (
    ModelTerm,
    SampleContext,
    SensorModel,
    compensate,
    compensated_estimate,
    model_from_dict,
)
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_effects import PathTiltTerm, ScaleFactorTerm
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import write_recording


def test_each_term_removes_what_its_effect_adds():
    rng = np.random.default_rng(1)
    n = 500
    a = rng.normal(0.0, 1.0, n)
    pos = np.cumsum(rng.normal(0.0, 1e-3, n))
    moving = rng.random(n) > 0.5
    temp = 25.0 + rng.normal(0.0, 1.0, n)
    other = 0.3 * np.sin(np.arange(n) / 20.0)
    rest = ~moving
    read = ((1.0 + 0.02) * a + 0.03 * G * pos + 0.05 * moving + 0.004 * (temp - 24.0)
            + 0.05 * (other - np.median(other[rest])))
    model = SensorModel((ModelTerm("cross_talk", {"gain": 0.05}),
                         ModelTerm("temperature_offset", {"offset_mps2_per_c": 0.004, "reference_c": 24.0}),
                         ModelTerm("motion_offset", {"offset_mps2": 0.05}),
                         ModelTerm("tilt", {"tilt_gradient_rad_per_m": 0.03}),
                         ModelTerm("scale_factor", {"scale_error_frac": 0.02})))
    ctx = SampleContext(np.arange(n) * 0.002, other, temp, pos_m=pos, moving=moving, rest=rest)
    assert np.allclose(compensate(model, read, ctx), a)
    assert model.uses_estimate and model.not_compensated == ()


def test_a_model_file_is_checked_where_it_is_read():
    with pytest.raises(ValueError, match="not an adxlgw-sensor-model"):
        model_from_dict({"format": "other"}, "m.json")
    with pytest.raises(ValueError, match="not a finite number"):
        model_from_dict({"format": "adxlgw-sensor-model", "version": 1,
                         "effects": [{"name": "tilt", "params": {"tilt_gradient_rad_per_m": "x"}}]}, "m.json")


def test_terms_that_need_the_estimate_are_iterated_until_it_settles():
    class Track:
        def __init__(self, acc):
            self.pos_m = np.cumsum(np.cumsum(acc)) * 1e-6
            self.standstill = np.zeros(acc.size, bool)

    model = SensorModel((ModelTerm("tilt", {"tilt_gradient_rad_per_m": 0.01}),))
    acc = np.r_[np.ones(50), -np.ones(50), np.zeros(50)]
    result = compensated_estimate(model, acc, SampleContext(np.arange(150) * 0.002), Track)
    assert 1 < result.passes <= 12 and result.settled
    assert np.allclose(result.acc_mps2, acc - 0.01 * G * result.track.pos_m, atol=1e-6)
    assert "passes with the estimate's position" in result.describe()


def test_a_correction_that_does_not_settle_says_so():
    """An estimate whose standstill decisions flip with the correction alternates between
    two answers pass after pass (the robot's horizontal moves without the hint): the last
    pass is not the model's answer, and the result says the passes did not settle."""
    class Track:
        def __init__(self, acc):
            # the estimator's own decision flips with the sign of what it is fed
            self.pos_m = np.full(acc.size, 0.1 if acc.mean() > 0 else -0.1)
            self.standstill = np.zeros(acc.size, bool)

    model = SensorModel((ModelTerm("tilt", {"tilt_gradient_rad_per_m": 0.01}),))
    result = compensated_estimate(model, np.zeros(100), SampleContext(np.arange(100) * 0.002), Track)
    assert result.passes == 12 and not result.settled
    assert result.last_step_m == pytest.approx(0.2)
    assert "did not settle after 12 passes" in result.describe() and "200.0 mm" in result.describe()


def _write(path, seed, terms):
    sim = simulate(build_profile(ScenarioSettings(name="paper", strokes=StrokeSettings(strokes=4))),
                   SensorParams(), seed=seed, error_terms=terms)
    write_recording(path, {"tick_hz": f"{sim.tick_hz:g}", "source": "simulation", "axis": "x", "seed": str(seed)},
                    sim.recording_columns())


def _stop_rms_mm(out):
    """The RMS of the stop errors `adxlgw estimate` prints (one line per stop)."""
    import re

    errors = [float(m.group(1)) for m in re.finditer(r"^\s*stop\s+\d+ at .*?:\s*([+-]?[\d.]+) mm", out, re.M)]
    assert errors, out
    return float(np.sqrt(np.mean(np.square(errors))))


@pytest.mark.slow
def test_a_model_fitted_on_one_recording_helps_another_of_the_same_setup(tmp_path, capsys):
    # one setup (a rail tilting 3°/m, a part 3 % hot), two recordings with other noise
    terms = (PathTiltTerm(gradient_rad_per_m=0.052), ScaleFactorTerm(scale_error_frac=0.03))
    fit_on, apply_to = tmp_path / "a.csv", tmp_path / "b.csv"
    _write(fit_on, 101, terms)
    _write(apply_to, 202, terms)
    model = tmp_path / "m.json"
    assert main(["diagnose", str(fit_on), "--model-out", str(model)]) == 0
    doc = json.loads(model.read_text())
    assert {e["name"] for e in doc["effects"]} >= {"tilt", "scale_factor"}
    capsys.readouterr()
    assert main(["estimate", str(apply_to), "--method", "smoothed", "--out", str(tmp_path / "e0.csv")]) == 0
    without = _stop_rms_mm(capsys.readouterr().out)
    assert main(["estimate", str(apply_to), "--method", "smoothed", "--model", str(model),
                 "--out", str(tmp_path / "e1.csv")]) == 0
    with_model = _stop_rms_mm(capsys.readouterr().out)
    assert with_model < 0.5 * without, (without, with_model)


def test_estimate_refuses_a_bad_model_file_with_exit_2(tmp_path):
    rec = tmp_path / "r.csv"
    _write(rec, 3, ())
    bad = tmp_path / "m.json"
    bad.write_text("{not json")
    assert main(["estimate", str(rec), "--model", str(bad), "--out", str(tmp_path / "e.csv")]) == 2
