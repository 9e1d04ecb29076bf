import numpy as np
import pytest

from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.drift_model import DriftModel
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes, standstill
from gateway.core.sensor_model import AxisSensor, SensorParams
from gateway.core.simulator import ErrorTerm, simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2

G = STANDARD_GRAVITY_MPS2


def test_same_seed_same_run_other_seed_other_noise():
    p = reciprocating_strokes(StrokeSettings(strokes=2))
    a, b, c = simulate(p, seed=5), simulate(p, seed=5), simulate(p, seed=6)
    assert np.array_equal(a.t1x, b.t1x) and np.array_equal(a.t_host_s, b.t_host_s)
    assert not np.array_equal(a.t1x, c.t1x)


def test_board_time_from_t2_counts_tracks_true_time_within_a_tick():
    sensor = SensorParams()
    run = simulate(standstill(120.0), sensor, seed=1)
    t_board = sample_times_s(run.t2, run.tick_hz)
    assert np.max(np.abs(t_board - run.t_s)) <= 1.0 / sensor.tick_hz + 1e-12
    assert np.mean(run.t2) == pytest.approx(sensor.t2_s * sensor.tick_hz, rel=1e-4)


def test_filtered_noise_has_the_data_sheet_density_and_bandwidth():
    from scipy.signal import welch

    from gateway.core.simulator import filtered_white_noise

    sensor = SensorParams()
    fs = 1.0 / sensor.t2_s
    noise = filtered_white_noise(np.random.default_rng(0), 400_000, sensor.t2_s, sensor)
    f, psd = welch(noise, fs=fs, nperseg=4096)
    low = (f > 1) & (f < 5)  # well inside the 50 Hz bandwidth: flat at N²
    assert np.sqrt(np.mean(psd[low])) == pytest.approx(sensor.noise_density_g_per_rthz, rel=0.05)
    at_fc = np.argmin(np.abs(f - sensor.bandwidth_hz))
    # one pole, sampled: −3 dB at f_c to within the discretisation (a few tenths of a dB)
    assert 10 * np.log10(psd[at_fc] / np.mean(psd[low])) == pytest.approx(-3.0, abs=0.6)
    assert np.std(noise) == pytest.approx(sensor.noise_rms_g, rel=0.03)


def test_standstill_counts_carry_sensor_noise_on_top_of_timer_quantisation():
    axis = AxisSensor(zero_g_offset_g=0.0, drift=DriftModel(0.0, 0.0, 1.0))
    quiet = SensorParams(x=axis, y=axis, noise_density_g_per_rthz=0.0)
    noisy = SensorParams(x=axis, y=axis)
    acc = {}
    for name, sensor in (("quiet", quiet), ("noisy", noisy)):
        run = simulate(standstill(200.0), sensor, seed=2)
        acc[name] = acceleration_mps2(run.t1x, run.t2, AxisCalibration()) / G
    # quantisation alone: about one tick of T1 in 1852 at 12.5 %/g, i.e. a few mg at most
    assert 0.5e-3 < np.std(acc["quiet"]) < 1.0 / 1852 / 0.125
    # independent errors add in variance
    noise_var = np.var(acc["noisy"]) - np.var(acc["quiet"])
    assert np.sqrt(noise_var) == pytest.approx(noisy.noise_rms_g, rel=0.1)
    assert abs(np.mean(acc["noisy"])) < 5e-4


def test_timer_counts_by_hand():
    from gateway.core.simulator import timer_counts

    class Fixed:
        def uniform(self):
            return 0.0

    edges = np.array([0.0, 2.0, 4.5])  # seconds, tick rate 10 Hz
    t1x, t1y, t2 = timer_counts(edges, np.array([0.5, 0.26]), np.array([0.04, 1.0]), 10.0, Fixed())
    assert t2.tolist() == [20, 25]
    assert t1x.tolist() == [10, 6]  # floor(2.0 + 0.26·2.5 = 2.65 s → 26) − 20
    assert t1y.tolist() == [0, 25]


def test_offset_and_drift_appear_in_the_counts():
    axis = AxisSensor(zero_g_offset_g=0.02, drift=DriftModel(c1_g=0.01, c2_g=0.0, time_constant_s=50.0))
    sensor = SensorParams(x=axis, noise_density_g_per_rthz=0.0)
    run = simulate(standstill(400.0), sensor, seed=3)
    acc_g = acceleration_mps2(run.t1x, run.t2, AxisCalibration()) / G
    first, last = acc_g[:2000].mean(), acc_g[-2000:].mean()
    assert first == pytest.approx(0.02 + 0.01 * (1 - np.exp(-2.0 / 50)), abs=1e-3)
    assert last == pytest.approx(0.03, abs=1e-3)


def test_motion_reaches_the_counts_and_clips_at_range():
    p = reciprocating_strokes(StrokeSettings(strokes=1, max_acc_mps2=30.0, stroke_m=0.3))
    sensor = SensorParams(noise_density_g_per_rthz=0.0)
    run = simulate(p, sensor, seed=0)
    acc = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    assert np.max(acc) == pytest.approx(2.0 * G, rel=0.01)  # 30 m/s² ≈ 3 g clipped at 2 g
    assert np.min(acc) == pytest.approx(-2.0 * G, rel=0.01)


def test_error_terms_are_one_small_addition():
    class Tilt(ErrorTerm):
        name = "tilt"

        def acceleration_g(self, ctx, x, y):
            return x + np.sin(np.radians(1.0)), y

    class DropEveryTenth(ErrorTerm):
        name = "loss"

        def samples(self, ctx, run):
            return run.select(np.arange(len(run)) % 10 != 5)

    p = standstill(10.0)
    base = simulate(p, seed=4)
    extended = simulate(p, seed=4, error_terms=(Tilt(), DropEveryTenth()))
    keep = np.arange(len(base)) % 10 != 5
    assert len(extended) == keep.sum() == len(base) - 498
    diff_g = (acceleration_mps2(extended.t1x, extended.t2, AxisCalibration())
              - acceleration_mps2(base.t1x[keep], base.t2[keep], AxisCalibration())) / G
    assert np.mean(diff_g) == pytest.approx(np.sin(np.radians(1.0)), rel=0.02)
    assert np.array_equal(extended.seq, base.seq[keep])


def test_host_arrival_follows_the_period_and_keeps_order():
    run = simulate(standstill(5.0), seed=7)
    end_of_period = run.t_s + run.t2 / run.tick_hz
    assert np.all(run.t_host_s > end_of_period)
    assert np.all(np.diff(run.t_host_s) >= 0)


def test_a_temperature_swing_of_a_given_phase():
    """TemperatureTerm.phase_rad fixes where the swing starts (an experiment that copies a
    documented case); unset, the phase is drawn per recording — and the draw is made
    either way, so the other random streams do not move."""
    from gateway.core.sensor_effects import TemperatureTerm

    at_peak = simulate(standstill(5.0), seed=3,
                       error_terms=(TemperatureTerm(0.0, cycle_s=40.0, phase_rad=np.pi / 2),))
    # the first reports: 25 + 4·cos(2π·t/40) for t within the first second
    assert at_peak.temp_c[0] == pytest.approx(29.0, abs=0.05)
    drawn = [simulate(standstill(5.0), seed=s, error_terms=(TemperatureTerm(0.0, cycle_s=40.0),)).temp_c[0]
             for s in (3, 4)]
    assert drawn[0] != drawn[1]
    assert np.array_equal(at_peak.t1x, simulate(standstill(5.0), seed=3, error_terms=(
        TemperatureTerm(0.0, cycle_s=40.0),)).t1x)
