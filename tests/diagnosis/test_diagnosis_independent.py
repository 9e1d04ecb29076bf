"""The diagnosis on data it was not built from: the independent generator
(testing/independent_generator), with hidden effects diagnose is not told about.

The slow test runs the first seed of the generator's one run after its design was frozen
(docs/diagnosis.md §7: seeds 50000+); the rows it checks were chosen before that run.
The generator shares no code with the simulator or the candidates (checked here).
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from gateway.core.diagnosis.context import DiagnosisInput, prepare, reference_resolution_block
from gateway.core.diagnosis.judgement import (
    SENSITIVITY_TOLERANCE_FRAC,
    physical,
    setup_range,
)
from testing.diagnosis_cases import estimator_settings
from testing.independent_generator.cases import IN_VOCABULARY, make_case, run_case
from testing.independent_generator.motion import strokes

ROOT = Path(__file__).resolve().parents[2]
GENERATOR_FILES = sorted((ROOT / "testing" / "independent_generator").glob("*.py"))
# the own simulator, and the diagnosis's candidate models: the generator makes each cause
# the way it works, not in the form a candidate fits
FORBIDDEN = ("gateway.core.simulator", "gateway.core.sensor_effects", "gateway.core.motion_profiles",
             "gateway.core.filters", "gateway.core.diagnosis.signal_effects", "gateway.core.diagnosis.signal_interface",
             "gateway.core.diagnosis.side_effects", "gateway.core.model_compensation")


@pytest.mark.parametrize("path", GENERATOR_FILES, ids=lambda p: p.name)
def test_the_independent_generator_shares_no_code_with_the_simulator(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    for name in names:
        assert not name.startswith(FORBIDDEN), f"{path.name} imports {name}"


# --- hidden effects: named, and nothing else named

FROZEN_RUN_SEED = 50000


@pytest.mark.slow
@pytest.mark.parametrize("effect", [None, "vibration", "reference_delay", "scale_factor", "cross_talk", "hum"],
                         ids=lambda e: e or "clean")
def test_a_hidden_effect_of_the_independent_generator_is_named_alone(effect):
    out = run_case(effect, FROZEN_RUN_SEED, estimator_settings())
    assert out.correct, out.describe()
    if effect in IN_VOCABULARY:
        for key, truth in out.truth.items():
            # the generator's parameters in diagnose's units, within a quarter
            assert out.estimates[key] == pytest.approx(truth, rel=0.25), out.describe()


# --- the generator itself


def test_s_curve_strokes_end_at_rest_where_they_began_within_the_limits():
    plan = strokes(np.random.default_rng(3), 6)
    t = np.arange(0.0, plan.end_s() + 0.5, 1e-4)
    pos, vel, acc = plan.evaluate(t)
    assert abs(pos[-1]) < 1e-9 and abs(vel[-1]) < 1e-9 and abs(acc[-1]) < 1e-9
    assert np.max(np.abs(vel)) <= 1.0 + 1e-9 and np.max(np.abs(acc)) <= 10.0 + 1e-9
    # jerk-limited: acceleration changes by at most j·dt per step
    assert np.max(np.abs(np.diff(acc))) <= 400.0 * 1e-4 + 1e-9
    # each stroke goes 30 cm
    assert np.max(pos) == pytest.approx(0.3, abs=1e-9)


def test_a_case_reads_back_as_a_board_recording_with_its_part_tolerances():
    case = make_case(None, 40001)
    d = case.data
    assert d.reference == "recorded" and d.reference_block == 1
    period = np.median(np.diff(d.t_s))
    assert period == pytest.approx(2e-3, rel=0.011)  # RSET within 1 %
    rest = np.abs(d.ref_vel_mps) == 0
    # at rest the axis reads its part's zero-g offset (within ±0.4 % duty = ±32 mg) and noise
    assert abs(np.nanmean(d.acc_mps2[rest])) < 0.033 * 9.80665
    host_delay = d.t_host_s - d.t_s
    assert np.median(np.diff(host_delay)) == pytest.approx(0.0, abs=1e-3)
    assert not case.other_axis_still and np.nanstd(d.other_mps2) > 0.1  # the other axis moves


# --- the judgement's parts


def _prep(block=1):
    t = np.arange(2000) * 2e-3
    data = DiagnosisInput(t, np.zeros(t.size), np.ones(t.size, bool), np.zeros(t.size, np.int64),
                          sensor_bandwidth_hz=49.7)
    prep = prepare(data)
    prep.block = block
    return prep


def test_setup_range_holds_the_calibration_tolerance_and_the_timing_convention():
    prep = _prep()
    assert setup_range("scale_factor", prep, np.array([0.99 * SENSITIVITY_TOLERANCE_FRAC]))
    assert setup_range("scale_factor", prep, np.array([1.01 * SENSITIVITY_TOLERANCE_FRAC])) is None
    # a part at the edge of its tolerance reads either side of it: outside only by 2σ
    edge = np.array([1.03 * SENSITIVITY_TOLERANCE_FRAC])
    assert "at 2σ" in setup_range("scale_factor", prep, edge, np.array([0.02 * SENSITIVITY_TOLERANCE_FRAC]))
    assert setup_range("scale_factor", prep, edge, np.array([0.01 * SENSITIVITY_TOLERANCE_FRAC])) is None
    assert setup_range("reference_delay", prep, np.array([1.5e-3]))
    assert setup_range("reference_delay", prep, np.array([4e-3])) is None
    assert setup_range("bandwidth", prep, np.array([183.0]))  # 0.87 ms of extra lag
    assert setup_range("bandwidth", prep, np.array([25.0])) is None
    assert setup_range("timing", prep, np.array([1.4e-3]))
    assert setup_range("timing", prep, np.array([4e-3])) is None
    # a coarse reference widens the timing by half its interval
    assert setup_range("reference_delay", _prep(block=16), np.array([4e-3]))


def test_physical_ranges_name_what_no_part_can_do():
    prep = _prep()
    assert "damping" in physical("vibration", prep, np.array([172.0, 0.9, 0.2, 0.0]))
    assert physical("vibration", prep, np.array([20.0, 0.05, 1.0, 0.0])) is None
    assert physical("bandwidth", prep, np.array([0.7]))
    assert physical("bandwidth", prep, np.array([12.0])) is None
    assert physical("scale_factor", prep, np.array([-0.44]))
    assert physical("nonlinearity", prep, np.array([0.5]))
    assert physical("nonlinearity", prep, np.array([0.01])) is None
    # a start-up backlog fitted as host timing (the held-out robot file): 1.4 s, −45 %
    assert "backlog" in physical("timing", prep, np.array([1.44, -0.455]))
    assert "backlog" in physical("timing", prep, np.array([0.004, 0.05]))
    assert physical("timing", prep, np.array([0.016, 20e-6])) is None


def test_reference_resolution_is_the_interval_of_a_coarse_position():
    t = np.arange(5000) * 0.0115
    knots = np.arange(0.0, t[-1] + 0.1, 0.0715)  # ~14 Hz robot positions, linearly interpolated
    pos = np.interp(t, knots, 0.3 * np.sin(knots))
    assert reference_resolution_block(t, pos) == pytest.approx(0.0715 / 0.0115, abs=1)
    fine = 0.3 * np.sin(t)
    assert reference_resolution_block(t, fine) == 1


def test_a_coarse_reference_is_read_as_its_velocity_change_per_period():
    t = np.arange(3000) * 2e-3
    vel = np.interp(t, [0, 1, 1.3, 3, 3.4, 6], [0, 0, 0.5, 0.5, 0, 0])
    pos = np.concatenate([[0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * np.diff(t))])
    data = DiagnosisInput(t, np.zeros(t.size), np.ones(t.size, bool), np.zeros(t.size, np.int64),
                          reference="recorded", ref_pos_m=pos, ref_vel_mps=vel,
                          ref_acc_mps2=np.gradient(vel, t), reference_block=8)
    prep = prepare(data)
    assert prep.block == 8
    mean = np.diff(vel) / np.diff(t)
    np.testing.assert_allclose(prep.reading_mps2[:-1], mean, atol=1e-9)
    # the comparison is made on block means: 8 samples each
    assert prep.whiten_masked(np.ones(t.size), prep.fit_mask).size == t.size // 8
