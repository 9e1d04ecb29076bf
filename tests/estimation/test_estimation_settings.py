"""Settings derived from the sensor model agree with what the simulated sensor produces,
and `adxlgw estimate` on a simulated recording prints its errors and draws its plot."""
import math

import numpy as np
import pytest

from gateway.cli import main
from gateway.core.conversion import AxisCalibration, acceleration_mps2
from gateway.core.drift_fit import allan_deviation
from gateway.core.drift_model import DriftModel
from gateway.core.estimator_settings import from_rest, from_sensor_model, quantisation_noise
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes, standstill
from gateway.core.sensor_model import AxisSensor, SensorParams
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import write_recording

QUIET_AXIS = AxisSensor(zero_g_offset_g=0.0, drift=DriftModel(0.0, 0.0, 1.0))


def _rest_mps2(sensor, seconds, seed):
    run = simulate(standstill(seconds), sensor, seed=seed)
    return acceleration_mps2(run.t1x, run.t2, AxisCalibration())


def test_quantisation_model_matches_the_simulated_timer():
    """With sensor noise on (without it the duty is constant and the fall latch's rounding
    is tied to the rise latch's, which no real signal does), what the timer adds on top
    of the sensor's known noise is the modelled rounding — to 25 %: the model takes the
    three latches' rounding as independent, but the simulated T2 is exactly periodic, so
    successive rise latches are not (measured: 15 % less variance). The total density
    that the filter uses is checked to 10 %."""
    sensor = SensorParams(x=QUIET_AXIS, y=QUIET_AXIS)
    acc_g = _rest_mps2(sensor, 400.0, seed=140) / G
    var, _, density_sq = quantisation_noise(sensor)
    d = acc_g - acc_g.mean()
    assert np.var(d) - sensor.noise_rms_g**2 == pytest.approx(var, rel=0.25)
    # (the lag-1 covariance of the rounding is not checked: with periodic latches it is
    # far from the independent model's D(1 − D)/12, and it is 4 % of the total variance)
    adev = allan_deviation(d, sensor.t2_s, m=np.array([64, 256]))
    n_read = np.median(adev.adev * np.sqrt(2 * adev.tau_s))
    assert n_read == pytest.approx(math.sqrt(density_sq + sensor.noise_density_g_per_rthz**2), rel=0.1)


def test_sensor_model_settings_match_a_simulated_rest():
    sensor = SensorParams(x=QUIET_AXIS)
    settings = from_sensor_model(sensor)
    acc = _rest_mps2(sensor, 200.0, seed=141)
    assert np.std(acc) == pytest.approx(settings.sample_noise_std_mps2, rel=0.05)
    rho1 = np.corrcoef(acc[1:], acc[:-1])[0, 1]
    assert rho1 == pytest.approx(settings.noise_autocorrelation[0], abs=0.05)
    adev = allan_deviation(acc, sensor.t2_s, m=np.array([64, 256, 1024]))
    density = np.median(adev.adev * np.sqrt(2 * adev.tau_s))
    assert density == pytest.approx(settings.accel_white_density_mps2_per_rthz, rel=0.1)
    # the variance test's false "motion" rate at rest is about what it was set for (1e-4)
    w = settings.window_samples
    windows = np.lib.stride_tricks.sliding_window_view(acc, w)
    rate = np.mean(windows.var(axis=1, ddof=1) > settings.window_variance_threshold_mps2_sq)
    assert rate < 2e-3
    # and settings from the same rest (the foreign-sensor path) agree with the model's
    rest = from_rest(acc[:2000], sensor.t2_s)
    assert rest.accel_white_density_mps2_per_rthz == pytest.approx(settings.accel_white_density_mps2_per_rthz, rel=0.3)
    assert rest.sample_noise_std_mps2 == pytest.approx(settings.sample_noise_std_mps2, rel=0.1)


def test_estimate_command_prints_errors_at_every_stop_and_plots(tmp_path, capsys):
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=3)), SensorParams(), seed=142)
    path = tmp_path / "paper.csv"
    write_recording(path, {"tick_hz": f"{run.tick_hz:g}", "axis": "x"}, run.recording_columns())
    out, plot = tmp_path / "est.csv", tmp_path / "est.png"
    assert main(["estimate", str(path), "--method", "smoothed", "--out", str(out), "--plot", str(plot)]) == 0
    text = capsys.readouterr().out
    assert text.count("  stop ") == 3 and "final:" in text and "RMS:" in text
    header = out.read_text().splitlines()[0].split(",")
    assert header[:4] == ["t_s", "pos_m", "vel_mps", "acc_mps2"]
    assert {"standstill", "bias_mps2", "pos_std_m", "innovation_mps2", "nis", "flags"} <= set(header)
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data.size == len(run.seq)
    assert abs(data["pos_m"][-1] - run.ref_pos_m[-1]) < 3e-3
    assert plot.stat().st_size > 10_000


def test_the_noise_is_measured_on_the_quiet_part_of_the_initial_rest():
    """A sensor whose axis stands while its mount vibrates (another axis moving): the
    initial rest (8σ off its start ends it) runs on through the vibration; the noise
    settings come from its quiet part only (reference_point.quiet_part: windowed F and t
    tests against the rest's own baseline). A rest of white noise alone is kept whole."""
    from gateway.core.reference_point import find_initial_rest, quiet_part

    rng = np.random.default_rng(29)
    period = 0.01
    # bounded noise (uniform, σ = 0.029 m/s²), so that no sample of the vibration comes 8σ off
    quiet = rng.uniform(-0.05, 0.05, 400)  # 4 s at rest
    # 6 s of a 13 Hz vibration of 0.12 m/s² on top: three times the noise's σ, at most 6σ off
    shaking = 0.12 * np.sin(2 * np.pi * 13.0 * period * np.arange(600)) + rng.uniform(-0.05, 0.05, 600)
    acc = np.concatenate([quiet, shaking])
    ok = np.ones(acc.size, dtype=bool)
    rest = find_initial_rest(acc, ok, period)
    assert rest.stop > 900  # the whole record is "the rest"
    part = quiet_part(acc, ok, rest, period)
    assert 380 <= part.stop <= 410
    assert abs(part.sample_std_mps2 - 0.1 / np.sqrt(12)) < 0.004
    plain = find_initial_rest(quiet, ok[:400], period)
    assert quiet_part(quiet, ok[:400], plain, period) == plain
