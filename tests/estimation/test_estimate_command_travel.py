"""adxlgw estimate --travel-m: the axis's travel (as the daemon's estimator.travel_m) bounds
how long an undecidable quiet stretch may be a cruise; a wrong travel is one line, exit 2."""
import numpy as np
import pytest

from gateway.cli import main
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.offline.recording import write_recording


def _recording(path) -> None:
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=1)), seed=7)
    t = run.t_s - run.t_s[0]
    acc = run.ref_acc_mps2 + np.random.default_rng(7).normal(0, 2e-3 * STANDARD_GRAVITY_MPS2, t.size)
    write_recording(path, {"source": "test"}, {"t_s": t, "acc_x_mps2": acc, "ref_pos_m": run.ref_pos_m})


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_the_travel_sets_the_quiet_stop(tmp_path, capsys, method):
    rec = tmp_path / "r.csv"
    _recording(rec)
    assert main(["estimate", str(rec), "--method", method, "--out", str(tmp_path / "o.csv"),
                 "--travel-m", "-0.1", "0.4"]) == 0
    printed = capsys.readouterr().out
    # 0.5 m at the speed floor (0.1 m/s): no cruise lasts 5 s within it
    assert "a stop after 5 s of quiet: the travel 0.5 m" in printed, printed
    assert main(["estimate", str(rec), "--method", method, "--out", str(tmp_path / "o.csv")]) == 0
    assert "a stop after 200 s of quiet: the travel 20 m" in capsys.readouterr().out


@pytest.mark.parametrize("travel", [["0.4", "-0.1"], ["0", "0"], ["-100000", "1"], ["nan", "1"]])
def test_a_wrong_travel_is_one_line_exit_2(tmp_path, capsys, travel):
    rec = tmp_path / "r.csv"
    _recording(rec)
    assert main(["estimate", str(rec), "--out", str(tmp_path / "o.csv"), "--travel-m", *travel]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--travel-m" in err[0], err
