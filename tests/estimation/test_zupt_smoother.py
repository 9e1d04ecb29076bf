"""The offline ZUPT smoother (gateway/core/zupt_smoother.py): rests found where they are,
cruises never taken for rests, the bias recovered, σ that covers — on records whose truth
is known, over many seeds."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import binom

from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_rest
from gateway.core.runs import true_runs
from gateway.core.zupt_smoother import smooth
from testing.robot_like_cases import robot_case

PERIOD_S = 0.01
NOISE_MPS2 = 0.02
# rest, move out (1 m/s² for 0.2 s, cruise 1 s at 0.2 m/s, −1 m/s²), rest, move back, rest
PROFILE = ((2.0, 0.0), (0.2, 1.0), (1.0, 0.0), (0.2, -1.0), (1.0, 0.0), (0.2, -1.0), (1.0, 0.0), (0.2, 1.0),
           (2.0, 0.0))


def synthetic(seed: int, bias_mps2: float):
    """A record from the profile: white noise, a constant bias; the truth's p, v and rests."""
    acc = np.concatenate([np.full(int(round(d / PERIOD_S)), a) for d, a in PROFILE])
    n = acc.size
    t = np.arange(n) * PERIOD_S
    vel = np.concatenate(([0.0], np.cumsum(acc[:-1]) * PERIOD_S))
    pos = np.concatenate(([0.0], np.cumsum(vel[:-1] * PERIOD_S + 0.5 * acc[:-1] * PERIOD_S ** 2)))
    z = acc + bias_mps2 + np.random.default_rng(seed).normal(0.0, NOISE_MPS2, n)
    rest = (np.abs(vel) < 1e-12) & (acc == 0.0)
    return t, z, pos, vel, rest


def settings_for(z):
    """The settings a rest gives (from_rest), with the noise the record was made with: these
    tests judge the smoother given its settings (from_rest's estimate of N from 1.5 s wanders
    by ±50 %: tests/estimation/)."""
    return replace(from_rest(z[:150], PERIOD_S), sample_noise_std_mps2=NOISE_MPS2,
                   accel_white_density_mps2_per_rthz=NOISE_MPS2 * np.sqrt(2.0 * PERIOD_S))


def test_rests_found_and_cruises_never_taken():
    """Every true rest is found (decisively), and no sample taken as a rest moves faster
    than the velocity test's resolution (the floor over its decisive sigmas: 20 mm/s)."""
    for seed in range(5):
        t, z, pos, vel, rest = synthetic(seed, 0.3)
        s = settings_for(z)
        res = smooth(t, z, np.ones(t.size, bool), np.zeros(t.size, np.int64), s)
        assert np.all(np.abs(vel[res.rest]) <= s.standstill_speed_floor_mps / 5.0 + 1e-12)
        for a, b in true_runs(rest):
            assert res.rest[a:b].mean() > 0.8, (seed, a, b)
        assert not res.untrusted.any()
        # the cruise (1 s at 0.2 m/s) is as quiet as a rest: it is never one
        assert not res.rest[np.abs(vel) >= 0.2 - 1e-12].any()


def test_bias_recovered_within_its_sigma():
    """The smoothed bias at the rests against the truth: within 4σ at every seed (with a
    correct σ, a 4σ miss has probability 6e-5 per seed)."""
    for seed in range(20):
        t, z, pos, vel, rest = synthetic(seed, -0.7)
        res = smooth(t, z, np.ones(t.size, bool), np.zeros(t.size, np.int64), settings_for(z))
        err = res.bias_mps2[rest] + 0.7
        assert np.all(np.abs(err) <= 4.0 * np.sqrt(res.bias_var[rest])), seed


def test_sigma_covers_the_rest_ends_on_many_seeds():
    """At the end of each rest the position error lies inside ±3σ: with a correct σ a miss
    has probability 0.27 % per rest end (the reported σ adds the sensitivity's share, so
    fewer); over 40 seeds × 3 rest ends, more than 3 misses would have probability < 1 %."""
    misses, ends = 0, 0
    for seed in range(40):
        t, z, pos, vel, rest = synthetic(1000 + seed, 0.1)
        track = estimate_series(t, z, method="zupt", settings=settings_for(z))
        for _a, b in true_runs(rest):
            k = b - 1
            ends += 1
            misses += abs(track.pos_m[k] - pos[k]) > 3.0 * track.pos_std_m[k]
    assert binom.sf(3, ends, 0.0027) < 0.01
    assert misses <= 3


@pytest.mark.parametrize("seed", [11, 12])
def test_simulated_robot_path_moves_within_sigma(seed):
    """The simulator's robot-like path (the sensor model's noise, 0.1 s and 0.5 s stops):
    each rest end within ±3σ or flagged — never confidently wrong."""
    t, z, ref, resting, settings = robot_case(seed, 0.0)
    track = estimate_series(t, z, method="zupt", settings=settings)
    for _a, b in true_runs(resting):
        k = b - 1
        assert abs(track.pos_m[k] - ref[k]) <= 3.0 * track.pos_std_m[k] or track.untrusted[k]


def test_a_record_that_ends_moving_is_flagged_and_covered():
    """Cut in the last move's cruise: the end is not a rest the data confirm. The estimate
    assumes it is (v = 0 at the last sample), says so (flag 256 from the last rest), and its
    σ covers the answer without that assumption."""
    t, z, pos, vel, rest = synthetic(3, 0.2)
    cut = int(round((2.0 + 0.2 + 1.0 + 0.2 + 1.0 + 0.2 + 0.5) / PERIOD_S))
    res = smooth(t[:cut], z[:cut], np.ones(cut, bool), np.zeros(cut, np.int64), settings_for(z))
    assert res.untrusted[-1]
    last_rest_end = true_runs(rest[:cut])[-1][1]
    assert res.untrusted[last_rest_end:].all()
    assert not res.untrusted[:int(round(2.0 / PERIOD_S))].any()


def test_one_missing_sample_is_bridged_by_its_neighbours_and_several_by_their_range():
    """A period that bridges one missing sample (an invalid one, or one lost after a valid
    one) adds one sample's noise over the bridged time; a gap of several adds the
    neighbours' half-difference too (the acceleration may have changed between them)."""
    from gateway.core.zupt_smoother import bridged_input

    n, sample_var = 12, 0.01 ** 2
    t = np.arange(n) * PERIOD_S
    acc = np.where(np.arange(n) < 6, 0.0, 2.0)  # a step: neighbours across it differ by 2 m/s²
    one_invalid = np.ones(n, bool)
    one_invalid[5] = False
    _, extra = bridged_input(t, acc, one_invalid, np.zeros(n, np.int64), sample_var)
    np.testing.assert_allclose(extra[5], sample_var * PERIOD_S ** 2)
    three_invalid = one_invalid.copy()
    three_invalid[3:6] = False
    _, extra = bridged_input(t, acc, three_invalid, np.zeros(n, np.int64), sample_var)
    np.testing.assert_allclose(extra[3:6], ((1.0 + 0.01) * PERIOD_S) ** 2)
    t_lost = t.copy()
    t_lost[6:] += PERIOD_S  # one sample lost after sample 5
    lost = np.zeros(n, np.int64)
    lost[6] = 1
    _, extra = bridged_input(t_lost, acc, np.ones(n, bool), lost, sample_var)
    np.testing.assert_allclose(extra[5], sample_var * (2 * PERIOD_S) ** 2)
    lost[6] = 2
    t_lost[6:] += PERIOD_S
    _, extra = bridged_input(t_lost, acc, np.ones(n, bool), lost, sample_var)
    np.testing.assert_allclose(extra[5], ((1.0 + 0.01) * 3 * PERIOD_S) ** 2)
    assert np.count_nonzero(extra) == 1


def test_forward_only_uses_no_sample_beyond_one_window_ahead():
    """`zupt-forward` is what a realtime estimator with this detector would publish: its
    position at a sample is the same whether the record goes on or ends one window and a
    sample later (a quiet window covers the samples it spans: one window of latency). The
    method with its backward pass and two-sided decisions does not have this property."""
    t, z, _pos, _vel, rest = synthetic(3, 0.3)
    s = settings_for(z)
    w = s.window_samples
    full = {m: estimate_series(t, z, method=m, settings=s).pos_m for m in ("zupt-forward", "zupt")}
    differs = {"zupt-forward": 0, "zupt": 0}
    in_motion_ends = 0
    # ends in a rest, mid-move, in a cruise, in the last rest
    for end in (300, 330, 370, 560, 900):
        for method in differs:
            cut = estimate_series(t[:end], z[:end], method=method, settings=s).pos_m
            settled = end - w - 1  # the samples a window ending before the cut has judged
            if not np.array_equal(cut[:settled], full[method][:settled]):
                differs[method] += 1
            if method == "zupt-forward" and end <= t.size and not rest[end - 2 * w:end].any():
                # deep in a move: no quiet window near the end in either record, so the
                # last sample is what the filter had there — not a stop assumed because
                # the record ends (a realtime estimator does not know it ends)
                in_motion_ends += 1
                assert cut[-1] == full[method][end - 1], end
    assert in_motion_ends >= 1
    assert differs["zupt-forward"] == 0 and differs["zupt"] > 0, differs
