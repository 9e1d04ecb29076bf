import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.simulator import simulate
from gateway.errors import RecordingError
from gateway.offline.recording import parse_recording, read_recording, to_acceleration, write_recording

REPO = Path(__file__).resolve().parents[2]
AIRBRAKES = REPO / "datasets" / "airbrakes-imu"


def adxlgw(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gateway.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120)


def test_simulated_recording_round_trips(tmp_path):
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=2)), seed=1)
    path = tmp_path / "r.csv"
    write_recording(path, {"tick_hz": "921600", "axis": "x"}, run.recording_columns())
    rec = read_recording(path)
    assert rec.form == "raw" and rec.metadata["format"] == "adxl-recording/1"
    for name, col in run.recording_columns().items():
        np.testing.assert_array_equal(rec.columns[name], col.astype(float))
    series = to_acceleration(rec)
    assert set(series.reference) == {"ref_pos_m", "ref_vel_mps", "ref_acc_mps2"}
    np.testing.assert_allclose(series.t_s, run.t_s, atol=2e-6)


def test_acceleration_form_and_unknown_metadata_are_kept():
    rec = parse_recording("# tick_hz=1\n# colour=blue\nt_s,acc_x_mps2,extra\n0,1.5,7\n0.01,,8\n")
    assert rec.form == "acceleration" and rec.metadata["colour"] == "blue"
    s = to_acceleration(rec)
    assert s.valid.tolist() == [True, False]


@pytest.mark.parametrize(
    "text, message",
    [
        ("a,b\n1,2\n", "neither recording form: raw form lacks column(s) seq, t1x, t1y, t2"),
        ("seq,t1x,t1y,t2\n0,1,1,2\n", "needs the metadata line '# tick_hz=…'"),
        ("# tick_hz=fast\nseq,t1x,t1y,t2\n0,1,1,2\n", "is not a positive number"),
        ("# tick_hz=921600\nseq,t1x,t1y,t2\n0,900,901,1843\n1,9x0,901,1843\n",
         "<f>:4: column 't1x': '9x0' is not a number"),
        ("t_s,acc_x_mps2\n0,1\n0.1,2,3\n", "<f>:3: has 3 cells, the header has 2"),
        ("t_s,acc_x_mps2\n0,1\n0,2\n", "<f>:3: column 't_s': sample times must increase"),
        ("# tick_hz=921600\nseq,t1x,t1y,t2\n0,900.5,901,1843\n", "column 't1x': 900.5 is not an integer count"),
        ("# only=metadata\n", "no header row"),
        ("t_s,acc_x_mps2,standstill_hint\n0,1,1\n0.1,2,\n0.2,2,0.5\n",
         "<f>:4: column 'standstill_hint': 0.5 is not 1 (at rest), 0 (moving) or empty (unknown)"),
    ],
)
def test_bad_recordings_name_file_line_and_column(text, message):
    with pytest.raises(RecordingError, match=None) as info:
        parse_recording(text, "<f>")
    assert message in str(info.value)
    assert str(info.value).startswith("<f>")


def test_cli_bad_recording_is_one_line_exit_2_no_traceback(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,acc_x_mps2\n0,1\n0.1,abc\n")
    out = tmp_path / "o.csv"
    # any offline command reading a recording reports the same way; import reads foreign CSVs
    r = adxlgw("import", bad, "--time-col", "t_s", "--acc-col", "acc_x_mps2", "--out", out)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert "bad.csv:3: column 'acc_x_mps2': 'abc' is not a number" in r.stderr
    assert "Traceback" not in r.stderr


def test_cli_simulate_writes_the_paper_scenario(tmp_path):
    out = tmp_path / "sim.csv"
    r = adxlgw("simulate", "--scenario", "paper", "--strokes", "4", "--seed", "3", "--out", out)
    assert r.returncode == 0, r.stderr
    rec = read_recording(out)
    assert rec.metadata["tick_hz"] == "921600" and rec.metadata["seed"] == "3"
    pos = rec.columns["ref_pos_m"]
    assert pos.max() == pytest.approx(0.3) and abs(pos[-1]) < 1e-12


def test_cli_rejects_bad_arguments_with_exit_2(tmp_path):
    r = adxlgw("simulate", "--strokes", "0", "--out", tmp_path / "x.csv")
    assert r.returncode == 2 and "must be at least 1" in r.stderr
    r = adxlgw("simulate", "--jerk-mps3", "-400", "--out", tmp_path / "x.csv")
    assert r.returncode == 2 and "--jerk-mps3" in r.stderr and "Traceback" not in r.stderr


def test_cli_simulate_an_s_curve_drive(tmp_path):
    """--jerk-mps3: the same strokes with the acceleration ramped, said in the metadata."""
    out = tmp_path / "s.csv"
    r = adxlgw("simulate", "--strokes", "2", "--jerk-mps3", "400", "--out", out)
    assert r.returncode == 0, r.stderr
    rec = read_recording(out)
    assert rec.metadata["jerk_mps3"] == "400"
    acc = rec.columns["ref_acc_mps2"]
    assert np.abs(acc).max() == pytest.approx(10.0)
    # levels between 0 and the full acceleration: the ramps (the paper's drive has none)
    assert np.count_nonzero((np.abs(acc) > 0.5) & (np.abs(acc) < 9.5)) > 0
    assert rec.columns["ref_pos_m"].max() == pytest.approx(0.3)


def test_import_real_airbrakes_recording(tmp_path):
    out = tmp_path / "zplus.csv"
    r = adxlgw("import", AIRBRAKES / "zplus.csv", "--time-col", "timestamp", "--time-unit", "ns",
               "--acc-col", "scaledAccelZ", "--acc-y-col", "scaledAccelX", "--acc-unit", "g", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "skipped 1529 rows" in r.stderr  # the sensor's own estimate rows, interleaved
    s = to_acceleration(read_recording(out))
    assert len(s) == 3058  # the dataset README's raw row count
    assert np.median(np.diff(s.t_s)) == pytest.approx(1e-3, rel=0.01)
    # at rest at the start: +z up, about 1 g
    assert np.mean(s.acc_mps2[:100]) == pytest.approx(9.81, abs=0.1)
