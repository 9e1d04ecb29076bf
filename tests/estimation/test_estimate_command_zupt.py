"""adxlgw estimate --method zupt: the command runs the offline ZUPT smoother
(gateway/core/zupt_smoother.py) through estimate_series, with the settings and the hint
the other filter methods get, and writes its track unchanged."""
from pathlib import Path

import numpy as np

from gateway.cli import main
from gateway.commands.estimate import settings_for
from gateway.core.estimator import estimate_series
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.offline.recording import open_recording, read_all, to_acceleration, write_recording

ROBOT = Path(__file__).resolve().parents[2] / "datasets" / "leiria-robot" / "eV50p_MPU6050RM3100.csv"


def _robot_with_hint(path):
    """The real robot file (vertical moves, ~87 samples/s) in the acceleration form, its
    machine's 'at rest' as the standstill_hint column, its reference."""
    d = np.genfromtxt(ROBOT, delimiter=",", names=True)
    write_recording(path, {"source": "test"}, {
        "t_s": d["sensor_time_s"] - d["sensor_time_s"][0], "acc_x_mps2": d["acc_z_g"] * STANDARD_GRAVITY_MPS2,
        "standstill_hint": d["robot_at_rest"].astype(float),
        "ref_pos_m": d["ref_z_m"] - d["ref_z_m"][0], "ref_vel_mps": d["ref_vz_mps"]})


def test_the_command_writes_the_track_of_estimate_series_zupt(tmp_path, capsys):
    rec, out = tmp_path / "robot.csv", tmp_path / "zupt.csv"
    _robot_with_hint(rec)
    assert main(["estimate", str(rec), "--method", "zupt", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "method zupt" in captured.out and "errors against the reference" in captured.out
    assert "using the recording's standstill_hint" in captured.err

    series = to_acceleration(read_all(open_recording(str(rec))))
    expected = estimate_series(series.t_s, series.acc_mps2, series.valid, method="zupt",
                               settings=settings_for(series, "acceleration", "auto", None),
                               standstill_hint=series.standstill_hint)
    written = np.genfromtxt(out, delimiter=",", names=True)
    assert written.size == len(expected)
    for name in ("pos_m", "vel_mps", "pos_std_m", "bias_mps2"):
        np.testing.assert_allclose(written[name], getattr(expected, name), rtol=1e-12, atol=1e-15, err_msg=name)
    np.testing.assert_array_equal(written["flags"], expected.flags)
    # --ignore-hint is honoured by zupt as by the other filter methods
    assert main(["estimate", str(rec), "--method", "zupt", "--ignore-hint", "--out", str(out)]) == 0
    assert "ignored" in capsys.readouterr().err
