"""The timing side test on host times a buffering adapter and a corrected host clock
make (the own simulator's sensor_effects.TimingTerm): the step found where it is, none
where there is none, nothing on the baseline link."""
from dataclasses import replace

import numpy as np
import pytest

from gateway.core.diagnosis.criterion import ALPHA
from gateway.core.diagnosis.host_timing import (
    TIMING_RESOLUTION_S,
    fit_timing,
    host_delays,
    judge_timing,
    predictive_logliks,
)
from gateway.core.diagnosis.side_effects import SIDE_EFFECTS
from testing.diagnosis_cases import SENSOR, make_case

ALPHA_SIDE = ALPHA / len(SIDE_EFFECTS)


def _judged(effects, seed, adjust=None):
    terms, data = make_case(effects, seed, adjust=adjust)
    d = host_delays(data.t_s, data.t_host_s, data.lost_before, SENSOR.t2_s)
    return terms, data, d, judge_timing(d.delay_s, d.t_s, TIMING_RESOLUTION_S, ALPHA_SIDE)


@pytest.mark.parametrize("step_s", [-0.020, 0.008])
def test_a_clock_step_is_found_with_its_size_and_place(step_s):
    terms, data, d, v = _judged(("timing",), 9200, adjust=lambda t: replace(
        t, latency_timer_s=0.006, clock_step_s=step_s, clock_rate_error=200e-6, step_at=0.4))
    assert v.cv.predictive(ALPHA_SIDE, v.extra_params)
    assert v.step_cv.predictive(ALPHA_SIDE, 2) and v.extra_params == 5
    assert v.fit.step_s == pytest.approx(step_s, abs=0.3e-3)
    true_k = int(np.argmax(data.t_host_s - data.t_s > data.t_host_s[0] - data.t_s[0] + step_s / 2)) if step_s > 0 \
        else int(np.argmax(np.diff(data.t_host_s) < step_s / 2)) + 1
    assert abs(v.fit.step_index - true_k) <= 3  # the packet the step fell in
    assert v.fit.hold_s == pytest.approx(terms[0].equivalent_hold_back_s(), rel=0.05)
    # the rate to within one sample period over the record: a timer that is a multiple of
    # the period meets the frames at a phase that drifts by up to a period (the edge with it)
    assert v.fit.rate == pytest.approx(200e-6, abs=SENSOR.t2_s / float(d.t_s[-1]))


def test_no_step_is_kept_where_the_clock_was_not_stepped():
    terms, _, _, v = _judged(("timing",), 9201, adjust=lambda t: replace(t, clock_step_s=0.0))
    assert v.cv.predictive(ALPHA_SIDE, v.extra_params)
    assert v.extra_params == 3 and v.fit.step_s == 0.0
    assert v.fit.hold_s == pytest.approx(terms[0].equivalent_hold_back_s(), rel=0.05)


@pytest.mark.parametrize("seed", [9100, 9101, 9102])
def test_the_baseline_link_is_not_timing(seed):
    _, _, _, v = _judged((), seed)
    assert not v.cv.predictive(ALPHA_SIDE, v.extra_params)
    assert v.extra_params == 3


def test_a_held_out_stretch_holding_the_step_is_predicted_over_its_places():
    # the others see only that the step lies in the stretch: the mixture over its places
    # predicts it about as well as knowing the place, far better than either end
    _, data, d, v = _judged(("timing",), 9202, adjust=lambda t: replace(t, clock_step_s=-0.015, step_at=0.5))
    n = d.t_s.size
    k = v.fit.step_index
    held = np.zeros(n, dtype=bool)
    held[k - 60:k + 60] = True
    out = fit_timing(d.delay_s, d.t_s, ~held, TIMING_RESOLUTION_S, with_step=True, start=v.fit)
    assert out.step_s == pytest.approx(v.fit.step_s, abs=0.3e-3)
    _, mixed = predictive_logliks(d.delay_s, d.t_s, ~held, held, out, TIMING_RESOLUTION_S)
    known = replace(out, step_index=k)
    _, at_place = predictive_logliks(d.delay_s, d.t_s, ~held, held, replace(known, window_lo=0, window_hi=-1),
                                     TIMING_RESOLUTION_S)
    ends = [predictive_logliks(d.delay_s, d.t_s, ~held, held, replace(out, step_index=e, window_lo=0, window_hi=-1),
                               TIMING_RESOLUTION_S)[1] for e in (k - 60, k + 60)]
    assert mixed > max(ends) + 50
    assert mixed > at_place - 10
