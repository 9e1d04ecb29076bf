"""Bad input: NaN/inf, a flagged axis, a gap, a recording too short — the estimator holds,
flags the health output, never produces NaN; the command says what it could not do."""
import math
from pathlib import Path

import numpy as np
import pytest

from gateway.cli import main
from gateway.core import estimator_kernel as K
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import RealtimeEstimator, estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import move_errors, summarise_errors
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.reference_point import NoRestError
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.offline.recording import write_recording

SETTINGS = from_sensor_model(SensorParams())
OUTPUTS = ("pos_m", "vel_mps", "acc_mps2", "bias_mps2", "pos_std_m", "vel_std_mps", "innovation_mps2", "nis",
           "zupt_velocity_error_mps")


@pytest.fixture(scope="module")
def strokes():
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=4)), SensorParams(), seed=120)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    return run, t, z


def _finite(track):
    for name in OUTPUTS:
        assert np.all(np.isfinite(getattr(track, name))), name


@pytest.mark.parametrize("method", ["raw", "paper", "realtime", "smoothed"])
def test_nan_inf_and_flagged_samples_are_held_and_flagged(strokes, method):
    run, t, z, = strokes
    z = z.copy()
    valid = np.ones(t.size, bool)
    rng = np.random.default_rng(121)
    bad = rng.choice(np.arange(1200, t.size), size=60, replace=False)
    z[bad[:20]] = np.nan
    z[bad[20:40]] = np.inf
    valid[bad[40:]] = False  # a flagged axis: the value is there but must not be used
    z[bad[40:]] = 50.0
    track = estimate_series(t, z, valid, method=method, settings=SETTINGS)
    _finite(track)
    assert np.all(track.flags[bad] & K.F_INPUT_INVALID)
    assert any("60 samples invalid" in note for note in track.notes)
    if method in ("realtime", "smoothed"):
        s = summarise_errors(t, track.pos_m, run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2)
        assert abs(s.stops[-1].error_m) < 5e-3  # 60 held samples of 2 ms: still millimetres


def _with_gap(t, z, start_s, samples):
    i = np.searchsorted(t, start_s)
    keep = np.ones(t.size, bool)
    keep[i:i + samples] = False
    lost = np.zeros(keep.sum(), np.int64)
    lost[i] = samples
    return i, t[keep], z[keep], lost


def test_a_gap_inside_a_steady_motion_is_bridged_and_flagged(strokes):
    """5 samples lost mid-cruise (2.1–2.3 s): the neighbours agree, the gap costs little."""
    run, t, z = strokes
    i, tg, zg, lost = _with_gap(t, z, 2.15, 5)
    with_gap = estimate_series(tg, zg, method="realtime", settings=SETTINGS, lost_before=lost)
    _finite(with_gap)
    assert with_gap.flags[i] & K.F_GAP
    keep = np.isin(t, tg)
    err = with_gap.pos_m - run.ref_pos_m[keep]
    assert np.all(np.abs(err) <= 3 * with_gap.pos_std_m + 1e-4)
    assert abs(err[-1]) < 2e-3 and not with_gap.untrusted.any()
    # from the time axis alone (acceleration-form recordings) the same gap is found
    assert np.array_equal(estimate_series(tg, zg, method="realtime", settings=SETTINGS).flags, with_gap.flags)


def test_a_gap_across_a_change_of_acceleration_loses_the_velocity_and_says_so(strokes):
    """20 ms lost across the end of the first acceleration (10 m/s² → cruise at 2.1 s): the
    velocity is unknown by ~0.1 m/s. The uncertainty grows, the position is flagged not
    trustworthy at once, and no quiet stretch after it is taken as a stop on the strength
    of a velocity the filter no longer has: the flag holds to the end (1 s dwells are
    shorter than quiet_stop_s), and the true error stays inside the 3σ band."""
    run, t, z = strokes
    i, tg, zg, lost = _with_gap(t, z, 2.09, 10)
    with_gap = estimate_series(tg, zg, method="realtime", settings=SETTINGS, lost_before=lost)
    without = estimate_series(t, z, method="realtime", settings=SETTINGS)
    _finite(with_gap)
    assert with_gap.flags[i] & K.F_GAP
    j = np.searchsorted(tg, 2.3)
    assert with_gap.pos_std_m[j] > 3 * without.pos_std_m[np.searchsorted(t, 2.3)]
    assert not without.untrusted.any()
    assert with_gap.untrusted[i:].all()  # from the gap on, to the end
    assert not with_gap.standstill[i:].any()
    err = with_gap.pos_m - run.ref_pos_m[np.isin(t, tg)]
    assert np.all(np.abs(err) <= 3 * with_gap.pos_std_m + 1e-4)


def test_a_gap_at_rest_across_the_start_of_a_stroke_is_not_taken_as_rest(strokes):
    """50 ms lost from just before the second stroke starts (at rest, the filter holding the
    position): the axis may have started moving in the gap. It used to be held as rest —
    metres off with every flag clear (docs/decisions/0160, gap_phase: 5 of 140 positions for
    50 ms gaps). Now the gap is propagated as motion: the start shows as uncertainty."""
    run, t, z = strokes
    moving = np.flatnonzero(run.ref_vel_mps != 0.0)
    second = moving[np.flatnonzero(np.diff(moving) > 1)[0] + 1]  # first sample of the second stroke
    i, tg, zg, lost = _with_gap(t, z, t[second - 5], 25)
    track = estimate_series(tg, zg, method="realtime", settings=SETTINGS, lost_before=lost)
    _finite(track)
    err = np.abs(track.pos_m - run.ref_pos_m[np.isin(t, tg)])
    assert np.all(err[i:] <= 3 * track.pos_std_m[i:] + 1e-4)
    assert err[-1] <= 5e-3 or track.untrusted[-1]
    assert err[-1] > 5e-3  # the case is real: the start in the gap cannot be recovered


@pytest.mark.parametrize("method", ["paper", "realtime", "smoothed"])
def test_too_short_to_find_a_standstill_raises(method):
    t = np.arange(30) * SETTINGS.sample_period_s
    with pytest.raises(NoRestError):
        estimate_series(t, np.full(t.size, 0.1), method=method, settings=SETTINGS)


def test_all_invalid_raises():
    t = np.arange(3000) * SETTINGS.sample_period_s
    with pytest.raises(NoRestError):
        estimate_series(t, np.full(t.size, np.nan), method="realtime", settings=SETTINGS)


def test_realtime_class_holds_on_none_nan_inf_and_time_going_back():
    est = RealtimeEstimator(SETTINGS)
    dt = SETTINGS.sample_period_s
    for k in range(200):
        e = est.step(k * dt, 0.1)
    assert e.standstill and e.initialised
    held = e.pos_m
    for value in (None, math.nan, math.inf, -math.inf):
        e = est.step(200 * dt, value)
        assert e.input_invalid and e.standstill
        assert all(math.isfinite(getattr(e, f)) for f in OUTPUTS)
        assert e.pos_m == held
    e = est.step(150 * dt, 0.1)  # the clock went back
    assert e.flags & K.F_TIME_ERROR
    assert all(math.isfinite(getattr(e, f)) for f in OUTPUTS)


def test_tare_zeroes_position_and_its_uncertainty(strokes):
    run, t, z = strokes
    est = RealtimeEstimator(SETTINGS)
    stop_end = np.searchsorted(t, 3.3)  # inside the first stop
    for k in range(stop_end):
        e = est.step(t[k], z[k])
    assert e.standstill and abs(e.pos_m - 0.3) < 2e-3 and e.pos_std_m > 0
    est.tare()
    e = est.step(t[stop_end], z[stop_end])
    assert e.pos_m == 0.0 and e.pos_std_m == 0.0
    for k in range(stop_end + 1, t.size):
        e = est.step(t[k], z[k])
    # three more strokes: back, out, back — the tared origin was at +0.3 m
    assert abs(e.pos_m - (run.ref_pos_m[-1] - 0.3)) < 3e-3


def test_request_bias_reestimate_widens_the_bias_and_the_next_standstill_measures_it():
    est = RealtimeEstimator(SETTINGS)
    dt = SETTINGS.sample_period_s
    rng = np.random.default_rng(122)
    k = 0
    for _ in range(500):
        est.step(k * dt, 0.1 + rng.normal(0, SETTINGS.sample_noise_std_mps2))
        k += 1
    settled = est.covariance[2, 2]
    est.request_bias_reestimate()
    assert est.covariance[2, 2] == pytest.approx(SETTINGS.bias_initial_std_mps2**2)
    for _ in range(500):  # the bias stepped by 0.02 m/s² (a temperature change, say)
        e = est.step(k * dt, 0.12 + rng.normal(0, SETTINGS.sample_noise_std_mps2))
        k += 1
    assert e.bias_mps2 == pytest.approx(0.12, abs=0.003)
    assert est.covariance[2, 2] < 10 * settled


def _write_acc(path, t, acc):
    write_recording(path, {"source": "test", "axis": "x"}, {"t_s": t, "acc_x_mps2": acc})


def test_command_exits_2_with_one_line_when_nothing_can_be_estimated(tmp_path, capsys):
    path = tmp_path / "short.csv"
    t = np.arange(20) * 0.002
    _write_acc(path, t, 0.1 + 0.01 * np.sin(t * 300))
    code = main(["estimate", str(path), "--method", "realtime", "--noise-from", "sensor", "--out",
                 str(tmp_path / "o.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "cannot estimate" in err[0] and "standstill" in err[0]
    assert not (tmp_path / "o.csv").exists()


def test_command_warns_about_invalid_samples_and_still_writes(tmp_path, capsys):
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=2)), SensorParams(), seed=123)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    z[1500:1510] = np.nan
    path = tmp_path / "holes.csv"
    _write_acc(path, t, z)
    out = tmp_path / "o.csv"
    code = main(["estimate", str(path), "--method", "smoothed", "--noise-from", "sensor", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0
    assert "warning: 10 samples invalid" in captured.err
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data.size == t.size and np.all(np.isfinite(data["pos_m"]))


ROBOT = Path(__file__).resolve().parents[2] / "datasets" / "leiria-robot" / "eV50p_MPU6050RM3100.csv"


def _robot_recording(path, first_row):
    """The real robot file (~87 samples/s, far from the ADXL's 500) from first_row on, with its reference."""
    d = np.genfromtxt(ROBOT, delimiter=",", names=True)[first_row:]
    t = d["sensor_time_s"] - d["sensor_time_s"][0]
    write_recording(path, {"source": "test"}, {
        "t_s": t, "acc_x_mps2": d["acc_z_g"] * 9.80665, "ref_pos_m": d["ref_z_m"] - d["ref_z_m"][0],
        "ref_vel_mps": d["ref_vz_mps"]})
    return d


def test_a_short_initial_rest_at_87_samples_per_second_still_estimates(tmp_path, capsys):
    """0.3 s of rest (26 samples: too few for an Allan deviation) used to be a traceback;
    the noise now comes from the rest's long-run variance and the source says so."""
    d = _robot_recording(tmp_path / "short.csv", 0)
    start = int(np.flatnonzero(d["robot_at_rest"] == 0)[0]) - 26
    _robot_recording(tmp_path / "short.csv", start)
    out = tmp_path / "o.csv"
    assert main(["estimate", str(tmp_path / "short.csv"), "--out", str(out)]) == 0
    assert "too short for an Allan deviation" in capsys.readouterr().out
    assert np.all(np.isfinite(np.genfromtxt(out, delimiter=",", names=True)["pos_m"]))


@pytest.mark.parametrize("method", ["paper", "realtime", "smoothed", "zupt"])
def test_a_recording_that_starts_moving_is_exit_2_in_one_line(tmp_path, capsys, method):
    d = np.genfromtxt(ROBOT, delimiter=",", names=True)
    moving = int(np.flatnonzero(d["robot_at_rest"] == 0)[0]) + 20
    _robot_recording(tmp_path / "moving.csv", moving)
    assert main(["estimate", str(tmp_path / "moving.csv"), "--method", method, "--out",
                 str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot estimate" in err[0] and "rest" in err[0]


def test_move_errors_take_each_move_from_rest_end_to_rest_end():
    at_rest = np.array([1, 1, 0, 0, 1, 1, 0, 1, 0, 0, 1])
    ref = np.array([0, 0, .1, .3, .5, .5, .5, .5, .4, .2, .1])  # +0.5, then 0 (skipped), then −0.4
    est = ref + np.array([0, 0, 0, 0, .05, .05, 0, .05, 0, 0, .01])
    moves = move_errors(est, ref, at_rest)
    assert [(m.start, m.end) for m in moves] == [(1, 5), (7, 10)]
    assert moves[0].error_m == pytest.approx(0.05) and moves[0].percent == pytest.approx(10.0)
    assert moves[1].ref_m == pytest.approx(-0.4) and moves[1].error_m == pytest.approx(-0.04)


@pytest.mark.parametrize("method", ["realtime", "smoothed", "zupt"])
def test_arrival_times_are_refused_with_the_way_out(tmp_path, capsys, method):
    """A logger's arrival times (a backlog flushed at 2.5 ms spacing, then bursts) are no
    sample clock: every path of `adxlgw estimate` checks its time axis and refuses it in one
    line that names the re-timing command, exit 2 — never a confidently wrong estimate."""
    rng = np.random.default_rng(29)
    n = 600
    true_t = np.arange(n) * 0.01
    burst = np.repeat(np.arange(0, n, 4) * 0.01 + 0.03, 4)[:n] + np.tile([0.0, 0.0025, 0.005, 0.0075], n // 4 + 1)[:n]
    acc = rng.normal(0.0, 0.02, n)
    path = tmp_path / "arrivals.csv"
    _write_acc(path, np.maximum.accumulate(burst), acc)
    assert true_t.size == n
    code = main(["estimate", str(path), "--method", method, "--out", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert "arrival times" in err[-1] and "adxlgw import --arrival-col" in err[-1] and str(path) in err[-1]
    assert not (tmp_path / "out.csv").exists()
