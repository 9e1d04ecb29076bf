"""A random walk of the bias is judged where the reading is the bias alone: at rest.

In motion the residual also carries whatever the motion's model lacks, and block means
of that wander too; a walk fitted there named the leftover of another effect (on the
independent generator `bias_random_walk` stood beside tilt and temperature). These tests
use the simulator only.
"""
import numpy as np
import pytest

from gateway.core.diagnosis.context import prepare
from gateway.core.diagnosis.side_effects import BiasRandomWalk
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from testing.diagnosis_cases import make_case, run_diagnosis

# strokes with rests long enough to hold the walk's blocks (the paper's 1 s dwells do not)
LONG_DWELLS = StrokeSettings(strokes=4, dwell_s=4.0, rest_start_s=4.0, rest_end_s=4.0)


def _walk(t_s: np.ndarray, k_mps2_per_rts: float, rng) -> np.ndarray:
    return np.cumsum(rng.normal(0.0, k_mps2_per_rts * np.sqrt(np.diff(t_s, prepend=t_s[0]))))


def test_a_wander_only_in_motion_is_not_a_walk_and_one_at_rest_is():
    _, data = make_case((), 3, strokes=LONG_DWELLS)
    prep = prepare(data)
    assert 0.3 < prep.rest.mean() < 0.9
    rng = np.random.default_rng(11)
    white = rng.normal(0.0, 1e-3 * G, data.t_s.size)
    walk = _walk(data.t_s, 2e-3 * G, rng)  # 2 mg/√s: unmissable where it is looked for
    test = BiasRandomWalk()
    in_motion = test.test(prep, white + np.where(prep.rest, 0.0, walk))
    assert not in_motion.predictive(1e-3), in_motion.params
    everywhere = test.test(prep, white + walk)
    assert everywhere.predictive(1e-3)
    assert everywhere.params["random_walk_ug_per_rts"][0] == pytest.approx(2000.0, rel=0.5)


def test_a_stroke_record_with_short_rests_says_it_cannot_see_a_walk():
    _, data = make_case((), 3)  # the paper's strokes: 1 s dwells, 0.3 s of each is settling
    prep = prepare(data)
    out = BiasRandomWalk().test(prep, np.zeros(data.t_s.size))
    assert "too few to see a walk" in out.detail and not out.predictive(1e-3)
    (walk,) = [c for c in run_diagnosis(data).candidates if c.name == "bias_random_walk"]
    assert walk.status == "rejected" and "too few to see a walk" in walk.reason


@pytest.mark.slow
def test_a_walk_between_strokes_is_named_from_the_rests():
    named, k_err = 0, []
    for seed in range(1, 6):
        terms, data = make_case(("bias_random_walk",), seed, strokes=LONG_DWELLS)
        result = run_diagnosis(data)
        names = [e.name for e in result.effects]
        assert names in ([], ["bias_random_walk"]), names
        if names:
            named += 1
            k = result.effects[0].params["random_walk_ug_per_rts"][0]
            k_err.append(abs(k / (terms[0].k_g_per_rts * 1e6) - 1.0))
    assert named >= 3 and max(k_err) < 0.5, (named, k_err)
