"""The extended sensor model in the daemon (`[calibration] model`, written by `adxlgw
diagnose --model-out`): checked like every file the config names (one line naming the
file and the key, exit 2), refused when the sample path cannot apply it as samples
arrive, a bad one refused at a reload with the running one kept, and — where the terms
need nothing but the sample and the board's reports — the daemon's estimate on the board's
bytes equal to `adxlgw estimate --model`'s on the same recording."""
from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.board_protocol import encode_hello, encode_sample, encode_status
from drivers.pty_port import PtyPort
from gateway.commands.model_option import estimate_with_model
from gateway.core.conversion import AxisCalibration, Calibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.model_compensation import MODEL_FORMAT, MODEL_VERSION
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.daemon.sample_pipeline import SamplePipeline
from gateway.daemon.settings import estimator_settings_from, model_terms_from
from tests.daemon_helpers import gateway_config, running_gateway


def model_file(path, *effects, version=MODEL_VERSION):
    path.write_text(json.dumps({"format": MODEL_FORMAT, "version": version, "source": "test",
                                "effects": [{"name": n, "params": p} for n, p in effects]}))
    return str(path)


SCALE_AND_TEMPERATURE = (("scale_factor", {"scale_error_frac": 0.04}),
                         ("temperature_offset", {"offset_mps2_per_c": 0.02, "reference_c": 25.0}))


def test_the_daemons_estimate_with_the_model_equals_estimate_model_on_the_same_bytes(tmp_path):
    """Scale and temperature need nothing but the sample and the board's latest report,
    so the daemon's per-sample correction (compiled) and the offline one (arrays) are the
    same formula on the same numbers: the positions are equal, sample for sample. The
    board's temperature changes mid-record (a STATUS report) to exercise the term."""
    path = model_file(tmp_path / "m.json", *SCALE_AND_TEMPERATURE)
    cfg = gateway_config(tmp_path, "emulated", calibration={"model": path})
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=3))), seed=4)
    p = SamplePipeline(Calibration(), estimator_settings_from(cfg), "x", start_at_rest=True,
                       model_terms=model_terms_from(cfg))
    report = dict(tick_hz=int(run.tick_hz), fw_major=1, fw_minor=0)
    p.feed(encode_hello(uptime_s=0, temp_centi_c=2400, **report))
    temp_c = np.empty(len(run))
    pos = []
    for k in range(len(run)):
        if k == len(run) // 2:  # the board warmed by 3 °C
            p.feed(encode_status(seq=0, uptime_s=1, temp_centi_c=2700, **report))
        temp_c[k] = 24.0 if k < len(run) // 2 else 27.0
        p.feed(encode_sample(k & 0xFFFF, int(run.t1x[k]), int(run.t1y[k]), int(run.t2[k]), int(run.flags[k])))
        pos.append(p.latest().pos_m)
    t = sample_times_s(run.t2, run.tick_hz)
    series = SimpleNamespace(t_s=t, acc_mps2=acceleration_mps2(run.t1x, run.t2, AxisCalibration()),
                             other_axis_mps2=None, temp_c=temp_c, standstill_hint=None)
    track, _ = estimate_with_model(path, series, from_sensor_model(), "raw", lambda acc, s: estimate_series(
        t, acc, method="realtime", settings=s, lost_before=np.zeros(t.size)))
    np.testing.assert_array_equal(np.array(pos), track.pos_m)
    # and the model did something: without it the positions differ
    plain = estimate_series(t, series.acc_mps2, method="realtime", settings=from_sensor_model(),
                            lost_before=np.zeros(t.size))
    assert np.max(np.abs(plain.pos_m - track.pos_m)) > 1e-3


def test_a_filter_term_adds_the_same_lag_to_the_daemons_estimator_as_offline(tmp_path):
    path = model_file(tmp_path / "m.json", ("bandwidth", {"cutoff_hz": 20.0}))
    cfg = gateway_config(tmp_path, "emulated", calibration={"model": path})
    lag = estimator_settings_from(cfg).sensor_lag_s - from_sensor_model(SensorParams()).sensor_lag_s
    assert lag == pytest.approx(1.0 / (2.0 * np.pi * 20.0))
    assert model_terms_from(cfg).shape == (0, 3)  # nothing to correct per sample


def test_motion_offset_is_applied_causally_with_the_filters_own_standstill(tmp_path):
    """The daemon corrects a motion offset where its filter's previous sample was not at
    standstill; `estimate --model` re-estimates the whole record with the track's flags
    until it settles (model_compensation.compensated_estimate). The two are therefore
    not equal sample for sample (a stop seen a window late offline is seen late here too,
    but the offline passes also use flags from after each sample); the daemon's must
    still move the estimate in the offset's direction."""
    path = model_file(tmp_path / "m.json", ("motion_offset", {"offset_mps2": 0.05}))
    cfg = gateway_config(tmp_path, "emulated", calibration={"model": path})
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=3))), seed=4)
    finals = []
    for terms in (np.zeros((0, 3)), model_terms_from(cfg)):
        p = SamplePipeline(Calibration(), from_sensor_model(), "x", start_at_rest=True, model_terms=terms)
        p.feed(encode_hello(uptime_s=0, temp_centi_c=2500, tick_hz=int(run.tick_hz), fw_major=1, fw_minor=0))
        p.feed(b"".join(encode_sample(k & 0xFFFF, int(run.t1x[k]), int(run.t1y[k]), int(run.t2[k]),
                                      int(run.flags[k])) for k in range(len(run))))
        finals.append(p.latest().pos_m)
    assert finals[1] < finals[0] - 1e-3  # an offset removed while moving: less distance forward


@pytest.mark.parametrize("effects, complaint", [
    ((("tilt", {"tilt_gradient_rad_per_m": 0.05}),), "tilt: cannot be applied as samples arrive"),
    ((("cross_talk", {"gain": 0.03}),), "cross_talk: cannot be applied as samples arrive"),
    ((("scale_factor", {"scale_error_frac": 0.5}),), "scale_error_frac = 0.5 is outside its physical range"),
    ((("wobble", {"x": 1.0}),), "unknown effect 'wobble'"),
    ((("temperature_offset", {"reference_c": 25.0}),), "parameter offset_mps2_per_c is missing"),
])
def test_config_check_refuses_a_model_the_daemon_cannot_use_in_one_line(tmp_path, effects, complaint):
    board = tmp_path / "ttyUSB0"
    board.touch()
    model = model_file(tmp_path / "m.json", *effects)
    path = tmp_path / "gw.toml"
    path.write_text(f'[serial]\nport = "{board}"\n[modbus]\nport = 0\n[can]\ninterface = "virtual"\nchannel = "x"\n'
                    f'[calibration]\nmodel = "{model}"\n')
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    errors = [line for line in r.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and f"{path}: calibration.model: {model}" in errors[0] and complaint in errors[0], errors


def test_config_check_accepts_a_model_the_daemon_can_apply_and_refuses_a_missing_file(tmp_path):
    board = tmp_path / "ttyUSB0"
    board.touch()
    model = model_file(tmp_path / "m.json", *SCALE_AND_TEMPERATURE, ("vibration", {
        "frequency_hz": 30.0, "damping_ratio": 0.05, "gain": 1.0, "quadrature": 0.0}))
    path = tmp_path / "gw.toml"
    base = f'[serial]\nport = "{board}"\n[modbus]\nport = 0\n[can]\ninterface = "virtual"\nchannel = "x"\n'
    path.write_text(base + f'[calibration]\nmodel = "{model}"\n')
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    path.write_text(base + f'[calibration]\nmodel = "{tmp_path / "none.json"}"\n')
    r = subprocess.run([sys.executable, "-m", "gateway.cli", "config", "--check", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and f"calibration.model: {tmp_path / 'none.json'}: cannot read" in r.stderr


class Reloadable:
    def __init__(self, cfg):
        self.cfg = cfg

    def __call__(self):
        return self.cfg


@pytest.fixture
def pty(tmp_path):
    port = PtyPort(tmp_path / "board")
    yield port
    port.close(remove_link=True)


def test_a_reload_applies_a_good_model_and_refuses_a_bad_one_keeping_the_running(tmp_path, pty):
    good = model_file(tmp_path / "good.json", *SCALE_AND_TEMPERATURE)
    cfg = gateway_config(tmp_path, str(pty.link), can={"enabled": False})
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            assert gw.pipeline.model_terms.shape == (0, 3)
            source.cfg = cfg.replace({"calibration.model": good})
            await gw.reload()
            assert gw.counters.config_reloads == 1 and gw.pipeline.model_terms.shape == (2, 3)
            running = gw.pipeline.model_terms
            for bad in (model_file(tmp_path / "tilt.json", ("tilt", {"tilt_gradient_rad_per_m": 0.05})),
                        model_file(tmp_path / "lag.json", ("bandwidth", {"cutoff_hz": 20.0})),
                        str(tmp_path / "missing.json")):
                source.cfg = cfg.replace({"calibration.model": bad})
                await gw.reload()
                assert gw.pipeline.model_terms is running and gw.cfg.calibration.model == good
            assert gw.counters.config_reload_errors == 3 and gw.counters.config_reloads == 1
            # the running file rewritten with a bad value, same name: refused too
            model_file(tmp_path / "good.json", ("scale_factor", {"scale_error_frac": 0.9}))
            source.cfg = cfg.replace({"calibration.model": good, "service.log_level": "debug"})
            await gw.reload()
            assert gw.counters.config_reload_errors == 4 and gw.pipeline.model_terms is running

    asyncio.run(scenario())
