"""The reported σ carries a velocity error the model cannot explain: a hand or a mount that
tilts the sensor for a moment during a move puts g·sin θ on the measured axis — no term of
the filter's noise model — and the stop's ZUPT finds a velocity error far beyond its σ_v.
Where in the move it arose the data do not say, so the position correction the ZUPT makes
(the white-noise shape, Cov(p, v)/Var(v)·Δv) is one answer among many; the reported σ must
cover them (kernel_output.zupt_beyond_chance, disagreement_var): never confidently wrong."""
import numpy as np
import pytest

from gateway.core.estimator import estimate_series
from gateway.core.evaluation import move_errors
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from testing.robot_like_cases import robot_case

TILT_RAD = np.deg2rad(1.2)  # a hand's or a loose mount's tilt: g·sin θ = 21 mg on the axis
TILT_S = 0.2                # for this long: while the first move accelerates (a tilt over a
                            # quiet cruise is an offset step, which the detector sees itself)


def _tilted(seed):
    t, z, ref, resting, settings = robot_case(seed, 0.0)
    moving = np.flatnonzero(~resting & (t > 1.0))
    start = t[moving[0]]
    tilt = (t >= start) & (t < start + TILT_S)
    return t, z + G * np.sin(TILT_RAD) * tilt, ref, resting, settings


def _first_stop(track, ref, resting):
    move = move_errors(track.pos_m, ref, resting)[0]
    return move.end, abs(track.pos_m[move.end] - ref[move.end])


@pytest.mark.parametrize("seed", [11, 12])
@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_a_tilt_during_a_move_stays_inside_three_sigma(method, seed):
    t, z, ref, resting, settings = _tilted(seed)
    track = estimate_series(t, z, method=method, settings=settings)
    end, err = _first_stop(track, ref, resting)
    # the tilt moved the stop by centimetres: a real error, not the noise's ...
    assert err > 0.02
    # ... that the filter's own σ (the same estimate without the tilt) claims far smaller ...
    t0, z0, ref0, resting0, _ = robot_case(seed, 0.0)
    plain = estimate_series(t0, z0, method=method, settings=settings)
    assert err > 3 * plain.pos_std_m[end]
    # ... and the σ reported with the tilt covers it, unflagged, without losing the move:
    # an honest σ, not a huge one (the error is more than a third of it)
    assert not track.untrusted[end]
    assert err <= 3 * track.pos_std_m[end] < 9 * err


def test_a_stop_the_noise_explains_adds_nothing():
    # no tilt: every stop's velocity innovation is chance, and σ is the filter's alone
    t, z, ref, resting, settings = robot_case(11, 0.0)
    track = estimate_series(t, z, method="realtime", settings=settings)
    end, err = _first_stop(track, ref, resting)
    assert track.pos_std_m[end] < 0.01
    assert err <= 3 * track.pos_std_m[end]
