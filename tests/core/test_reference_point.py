"""The initial rest of a recording: where the offset and the noise are measured."""
import numpy as np
import pytest

from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.reference_point import find_initial_rest, resolution
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2


def strokes_with_logger_noise(step_mg: float | None, seed: int = 21):
    """The paper's strokes' true acceleration plus 2 mg of noise, quantised to step_mg as
    a logger with that resolution writes it; and the index of the first moving sample."""
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=2)), seed=seed)
    acc = run.ref_acc_mps2 + np.random.default_rng(seed).normal(0, 2e-3 * STANDARD_GRAVITY_MPS2, run.t_s.size)
    if step_mg is not None:
        step = step_mg * 1e-3 * STANDARD_GRAVITY_MPS2
        acc = np.round(acc / step) * step
    first_move = int(np.flatnonzero(np.abs(run.ref_acc_mps2) > 0)[0])
    return acc, float(np.median(np.diff(run.t_s))), first_move


@pytest.mark.parametrize("step_mg", [None, 1.0, 10.0, 20.0])
def test_the_rest_ends_where_the_motion_starts_whatever_the_logger_resolution(step_mg):
    # at 10 mg a still rest is one value with a one-step flicker now and then (2 mg of
    # noise crosses half a step in ~1 % of samples): that flicker was taken for motion
    # 0.2 s into a 2 s rest, and the recording refused
    acc, period_s, first_move = strokes_with_logger_noise(step_mg)
    rest = find_initial_rest(acc, np.ones(acc.size, bool), period_s)
    assert first_move - int(0.2 / period_s) <= rest.stop <= first_move, (rest.stop, first_move)


def test_a_one_step_flicker_is_not_motion_a_lasting_step_or_a_jump_is():
    acc = np.zeros(2000)
    acc[150::97] = 0.1  # a one-step flicker on a rest with no noise (the data's step: 0.1)
    held = acc.copy()
    held[1500:] = 0.1  # one step, held: the axis moves (or the offset did)
    rest = find_initial_rest(held, np.ones(acc.size, bool), 0.002)
    assert 1450 <= rest.stop <= 1500, rest.stop
    jump = acc.copy()
    jump[1200] = 0.5  # five steps off, even for one sample: ends the rest as it always did
    rest = find_initial_rest(jump, np.ones(acc.size, bool), 0.002)
    assert 1150 <= rest.stop <= 1200, rest.stop


def test_resolution_is_the_smallest_step_between_values():
    assert resolution([0.3, 0.1, 0.1, 0.2]) == pytest.approx(0.1)
    assert resolution([5.0, 5.0]) == 0.0
    assert resolution(np.random.default_rng(0).normal(size=1000)) < 1e-2
