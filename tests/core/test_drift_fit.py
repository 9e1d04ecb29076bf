"""The drift fit and its judges: Ljung–Box and the Allan deviation against independent
computations, the fit against the simulator's known drift, and `adxlgw fit-drift`."""
import json
import math

import numpy as np
import pytest
from scipy.stats import chi2

from gateway.cli import main
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.drift_fit import FittedDrift, allan_deviation, fit_drift, ljung_box, noise_terms
from gateway.core.drift_model import DriftModel
from gateway.core.motion_profiles import standstill
from gateway.core.sensor_model import AxisSensor, SensorParams
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.offline.recording import write_recording


def test_ljung_box_by_hand():
    x = np.array([1.0, 3.0, 2.0, 5.0, 4.0, 6.0, 5.0, 8.0, 7.0, 9.0, 8.0, 10.0])
    n, h = x.size, 3
    d = x - x.mean()
    rho = [sum(d[i] * d[i + k] for i in range(n - k)) / sum(v * v for v in d) for k in range(1, h + 1)]
    q = n * (n + 2) * sum(r * r / (n - k) for k, r in enumerate(rho, start=1))
    lb = ljung_box(x, lags=h)
    assert lb.statistic == pytest.approx(q, rel=1e-12)
    assert lb.p_value == pytest.approx(chi2.sf(q, h), rel=1e-12)


def test_ljung_box_size_on_white_noise_and_power_on_ar1():
    rng = np.random.default_rng(130)
    p_white = [ljung_box(rng.standard_normal(500)).p_value for _ in range(200)]
    assert 0.02 < np.mean(np.array(p_white) < 0.05) < 0.09  # ≈ 5 % false alarms
    e = rng.standard_normal(500)
    ar = np.empty(500)
    ar[0] = e[0]
    for k in range(1, 500):
        ar[k] = 0.3 * ar[k - 1] + e[k]
    assert ljung_box(ar).p_value < 1e-4


def test_overlapping_allan_deviation_against_a_plain_loop():
    rng = np.random.default_rng(131)
    x = rng.standard_normal(300) + np.linspace(0, 1, 300)
    period = 0.01
    got = allan_deviation(x, period, m=np.array([1, 3, 7, 20]))
    for m, value in zip([1, 3, 7, 20], got.adev, strict=False):
        means = np.array([x[i:i + m].mean() for i in range(x.size - m + 1)])  # overlapping cluster means
        diffs = means[m:] - means[:-m]
        assert value == pytest.approx(math.sqrt(0.5 * np.mean(diffs**2)), rel=1e-9)


def test_allan_of_white_noise_and_of_a_random_walk_reads_n_and_k():
    rng = np.random.default_rng(132)
    period, n = 0.002, 400_000
    density = 200e-6  # one-sided, per √Hz
    white = rng.standard_normal(n) * density / math.sqrt(2 * period)
    terms = noise_terms(allan_deviation(white, period), min_tau_s=10 * period, record_s=n * period)
    assert terms.white_density_per_rthz == pytest.approx(density, rel=0.05)
    assert terms.rate_random_walk_per_rts is None and terms.bias_instability is None
    k = 5e-5  # crosses the white noise at τ ≈ 5 s, well inside the 800 s record's reliable range
    walk = np.cumsum(rng.standard_normal(n)) * k * math.sqrt(period)
    both = allan_deviation(white + walk, period)
    terms = noise_terms(both, min_tau_s=10 * period, record_s=n * period)
    assert terms.white_density_per_rthz == pytest.approx(density, rel=0.1)
    assert terms.rate_random_walk_per_rts == pytest.approx(k, rel=0.3)
    assert terms.random_walk_bound_per_rts >= 0.7 * k


def _standstill_g(seconds, drift, seed, offset_g=0.01):
    sensor = SensorParams(x=AxisSensor(zero_g_offset_g=offset_g, drift=drift))
    run = simulate(standstill(seconds), sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    return t, acceleration_mps2(run.t1x, run.t2, AxisCalibration()) / STANDARD_GRAVITY_MPS2


def test_fit_recovers_the_simulated_drift_and_finds_the_residual_white():
    truth = DriftModel(c1_g=0.0025, c2_g=0.0, time_constant_s=300.0)
    t, acc_g = _standstill_g(1800.0, truth, seed=133)
    fit = fit_drift(t, acc_g)
    assert abs(fit.model.c1_g - truth.c1_g) < 4 * fit.c1_std_g
    assert abs(fit.model.time_constant_s - truth.time_constant_s) < 4 * fit.time_constant_std_s
    assert abs(fit.model.c2_g - 0.01) < 4 * fit.c2_std_g + 2e-4  # offset + the timer's rounding bias
    assert fit.c1_std_g < 1e-4 and fit.time_constant_std_s < 30
    assert fit.whiteness.white()
    assert fit.noise.white_density_per_rthz == pytest.approx(229e-6, rel=0.1)  # sensor ⊕ quantisation


def test_a_wrong_model_leaves_a_residual_that_is_not_white():
    t, acc_g = _standstill_g(1800.0, DriftModel(0.0, 0.0, 1.0), seed=134)
    wander = 3e-4 * np.sin(2 * np.pi * t / 120.0)  # a 2-minute wander the model cannot follow
    fit = fit_drift(t, acc_g + wander)
    assert fit.whiteness.p_value < 1e-6


def test_fit_refuses_a_record_too_short():
    t, acc_g = _standstill_g(10.0, DriftModel(0.0, 0.0, 1.0), seed=135)
    with pytest.raises(ValueError, match="blocks"):
        fit_drift(t, acc_g)


def test_fitted_drift_round_trips():
    f = FittedDrift(DriftModel(0.002, 0.01, 900.0), 2.2e-4, 3e-6, False)
    assert FittedDrift.from_dict(json.loads(json.dumps(f.to_dict()))) == f


def test_fit_drift_command_prints_the_judgement_and_writes_plot_and_model(tmp_path, capsys):
    truth = DriftModel(c1_g=0.003, c2_g=0.0, time_constant_s=60.0)
    sensor = SensorParams(x=AxisSensor(zero_g_offset_g=0.01, drift=truth))
    run = simulate(standstill(400.0), sensor, seed=136)
    path = tmp_path / "still.csv"
    write_recording(path, {"tick_hz": f"{run.tick_hz:g}", "axis": "x"}, run.recording_columns())
    plot, model = tmp_path / "drift.png", tmp_path / "drift.json"
    assert main(["fit-drift", str(path), "--plot", str(plot), "--model-out", str(model)]) == 0
    out = capsys.readouterr().out
    assert "C1 = +3.0" in out and "Ljung–Box" in out and "p = " in out and "N = " in out
    assert plot.stat().st_size > 10_000
    fitted = FittedDrift.from_dict(json.loads(model.read_text()))
    assert fitted.model.time_constant_s == pytest.approx(60.0, rel=0.2)
    # the estimator takes it
    est = tmp_path / "est.csv"
    assert main(["estimate", str(path), "--drift-model", str(model), "--out", str(est)]) == 0
    assert "fitted drift" in capsys.readouterr().out


def test_fit_drift_command_exits_2_on_a_short_record(tmp_path, capsys):
    run = simulate(standstill(5.0), SensorParams(), seed=137)
    path = tmp_path / "short.csv"
    write_recording(path, {"tick_hz": f"{run.tick_hz:g}"}, run.recording_columns())
    assert main(["fit-drift", str(path), "--plot", str(tmp_path / "p.png")]) == 2
    assert "cannot fit" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_fit_drift_command_streams_and_gives_the_in_memory_fit(tmp_path, capsys, monkeypatch, suffix):
    """The command reads the recording chunk by chunk (many here: small CSV blocks, small
    Parquet batches, small residual blocks) and keeps it on disk between its passes; its fit
    is the one of the whole record in memory — the model to the bit, the rest to rounding."""
    from gateway.core import drift_fit
    from gateway.offline.recording import read_recording, to_acceleration
    from gateway.offline.recording import sources as reader

    sensor = SensorParams(x=AxisSensor(zero_g_offset_g=0.01, drift=DriftModel(0.003, 0.0, 60.0)))
    run = simulate(standstill(200.0), sensor, seed=138)
    path = tmp_path / f"still{suffix}"
    write_recording(path, {"tick_hz": f"{run.tick_hz:g}", "axis": "x"}, run.recording_columns())
    series = to_acceleration(read_recording(path))
    whole = fit_drift(series.t_s, np.where(series.valid, series.acc_mps2, np.nan) / STANDARD_GRAVITY_MPS2)
    seen = {}
    real_passes = drift_fit.fit_drift_passes

    def spy(passes, scratch, period_s=None, block_s=1.0):
        seen["chunks"] = sum(1 for _ in passes())  # the first pass: from the file
        seen["fit"] = real_passes(passes, scratch, period_s, block_s)
        return seen["fit"]

    monkeypatch.setattr(reader, "BLOCK_BYTES", 1 << 16)
    monkeypatch.setattr(reader, "PARQUET_BATCH_ROWS", 4096)
    monkeypatch.setattr(drift_fit, "BLOCK_SAMPLES", 5000)
    monkeypatch.setattr("gateway.commands.fit_drift.fit_drift_passes", spy)
    model = tmp_path / "drift.json"
    assert main(["fit-drift", str(path), "--plot", str(tmp_path / "p.png"), "--model-out", str(model)]) == 0
    capsys.readouterr()
    streamed = seen["fit"]
    assert seen["chunks"] >= 10
    assert streamed.model == whole.model
    np.testing.assert_array_equal(streamed.block_mean_g, whole.block_mean_g)
    assert streamed.whiteness == whole.whiteness
    np.testing.assert_allclose(streamed.allan.adev, whole.allan.adev, rtol=1e-12)
    assert streamed.residual_rms_g == pytest.approx(whole.residual_rms_g, rel=1e-12)
    assert streamed.full_rate_lag1 == pytest.approx(whole.full_rate_lag1, rel=1e-12)
    assert FittedDrift.from_dict(json.loads(model.read_text())).model == whole.model
