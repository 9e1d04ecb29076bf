"""adxlgw estimate --skip-s: a recording whose first samples are a sensor settling at
power-up (not motion) is refused with a way out, and estimated with it."""
import numpy as np
import pytest

from gateway.cli import main
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.offline.recording import write_recording


def _strokes():
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=2)), seed=5)
    return run, run.t_s - run.t_s[0]


def _settling_recording(path, settle_mps2: float = 3.0, tau_s: float = 0.0032, from_s: float = 0.0):
    """The paper's strokes as a logger writes them (acceleration form, 2 mg of noise, the
    reference), the output filter settling from settle_mps2 off at power-up; rows from
    from_s on."""
    run, t = _strokes()
    acc = run.ref_acc_mps2 + np.random.default_rng(5).normal(0, 2e-3 * STANDARD_GRAVITY_MPS2, t.size)
    acc = acc + settle_mps2 * np.exp(-t / tau_s)
    keep = t >= from_s
    write_recording(path, {"source": "test"}, {
        "t_s": t[keep], "acc_x_mps2": acc[keep], "ref_pos_m": run.ref_pos_m[keep],
        "ref_vel_mps": run.ref_vel_mps[keep]})


@pytest.mark.parametrize("method", ["realtime", "smoothed", "paper", "zupt"])
def test_a_settling_start_is_refused_with_the_way_out_and_estimated_with_it(tmp_path, capsys, method):
    rec = tmp_path / "settling.csv"
    _settling_recording(rec)
    out = tmp_path / "o.csv"
    assert main(["estimate", str(rec), "--method", method, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot estimate" in err[0] and "--skip-s" in err[0], err
    assert not out.exists()

    assert main(["estimate", str(rec), "--method", method, "--out", str(out), "--skip-s", "0.02"]) == 0
    capsys.readouterr()
    track = np.genfromtxt(out, delimiter=",", names=True)
    assert track["t_s"][0] >= 0.02 and np.all(np.isfinite(track["pos_m"]))
    # the same recording written without its first 0.02 s: the same estimate, number for number
    clean = tmp_path / "clean.csv"
    _settling_recording(clean, from_s=0.02)
    ref_out = tmp_path / "ref.csv"
    assert main(["estimate", str(clean), "--method", method, "--out", str(ref_out)]) == 0
    reference = np.genfromtxt(ref_out, delimiter=",", names=True)
    np.testing.assert_array_equal(track["pos_m"], reference["pos_m"])


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_the_reference_is_measured_from_where_the_estimate_begins(tmp_path, capsys, method):
    # skip past the first move into the dwell after it: the axis stands 0.3 m out there;
    # the estimate begins at 0, so the reference must too (else every error is ~300 mm)
    run, t = _strokes()
    moved = np.flatnonzero(np.abs(run.ref_pos_m) > 0.29)[0]
    dwell_s = float(t[moved]) + 0.2
    assert abs(run.ref_vel_mps[np.searchsorted(t, dwell_s)]) == 0.0  # (still in the dwell)
    rec = tmp_path / "r.csv"
    _settling_recording(rec, settle_mps2=0.0)
    assert main(["estimate", str(rec), "--method", method, "--out", str(tmp_path / "o.csv"),
                 "--skip-s", f"{dwell_s:.4f}"]) == 0
    printed = capsys.readouterr().out
    final_mm = float(printed.split("final:")[1].split("mm")[0])
    assert abs(final_mm) < 5, printed


@pytest.mark.parametrize("value", ["-1", "abc", "nan", "inf"])
def test_a_wrong_skip_is_one_line_exit_2(tmp_path, capsys, value):
    rec = tmp_path / "r.csv"
    _settling_recording(rec)
    with pytest.raises(SystemExit) as stop:
        main(["estimate", str(rec), "--out", str(tmp_path / "o.csv"), "--skip-s", value])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--skip-s" in err[-1] and "duration" in err[-1]


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_skipping_everything_is_one_line_exit_2(tmp_path, capsys, method):
    rec = tmp_path / "r.csv"
    _settling_recording(rec)
    assert main(["estimate", str(rec), "--method", method, "--out", str(tmp_path / "o.csv"),
                 "--skip-s", "1e6"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--skip-s" in err[0], err
