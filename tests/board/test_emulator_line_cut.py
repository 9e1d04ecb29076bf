"""The emulated board's line cut (`adxlgw emulate --cut-after S --cut-for S`): nothing it
writes during a cut arrives, while its seq and clock run on — samples lost, as on a UART
wire pulled and put back."""
import itertools
import subprocess

import pytest

from drivers.board_protocol import sample_at, seq_step
from gateway.core.scenarios import ScenarioSettings
from gateway.core.sensor_model import BOARD_SENSOR
from gateway.emulator import EmulatorSettings, FaultSettings, board_schedule, in_line_cut
from tests.daemon_helpers import CLI

PERIOD_S = BOARD_SENSOR.t2_s  # T2 = RSET / 125 MΩ (ADXL202 data sheet), with the part's error


def schedule(faults: FaultSettings, seconds: float, seed: int = 4):
    settings = EmulatorSettings(scenario=ScenarioSettings(name="standstill", standstill_s=seconds),
                                seed=seed, faults=faults)
    return list(board_schedule(settings))


def sample_seqs(chunks):
    return [(c.due_s, sample_at(c.data, 0)[0]) for c in chunks if c.kind == "sample"]


def test_a_cut_loses_what_the_board_wrote_meanwhile_and_its_seq_runs_on():
    cut = FaultSettings(cut_after_s=2.0, cut_for_s=0.6)
    whole, with_cut = schedule(FaultSettings(), 5.0), schedule(cut, 5.0)
    # nothing due inside the cut arrives, everything else does, unchanged and in order
    assert [c for c in whole if not in_line_cut(c.due_s, cut)] == with_cut
    assert not any(2.0 <= c.due_s < 2.6 for c in with_cut)
    assert any(c.kind == "status" and 2.0 <= c.due_s < 2.6 for c in whole)  # a STATUS was cut too
    # the seq jumps over the cut by the samples the board wrote in it (0.6 s / 2 ms)
    gaps = []
    for (_, last), (due, seq) in itertools.pairwise(sample_seqs(with_cut)):
        lost, _ = seq_step(last, seq)
        if lost:
            gaps.append((due, lost))
    assert len(gaps) == 1
    due, lost = gaps[0]
    assert due == pytest.approx(2.6, abs=2 * PERIOD_S)
    assert lost == pytest.approx(0.6 / PERIOD_S, abs=2)


def test_no_cut_by_default_and_one_cut_only():
    assert not any(in_line_cut(t / 100, FaultSettings()) for t in range(1000))
    faults = FaultSettings(cut_after_s=1.5, cut_for_s=0.5)
    cut = [t / 100 for t in range(1000) if in_line_cut(t / 100, faults)]
    assert cut[0] == 1.5 and cut[-1] == 1.99 and len(cut) == 50


@pytest.mark.parametrize("args, message", [
    (["--cut-for", "1"], "--cut-for without --cut-after: the line is never cut"),
    (["--cut-after", "1", "--cut-for", "0"], "--cut-for: '0' must be a positive number"),
    (["--cut-after", "-2"], "--cut-after: '-2' must be a number ≥ 0"),
])
def test_a_cut_that_cannot_be_is_refused_in_one_line(args, message):
    r = subprocess.run([*CLI, "emulate", *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert message in r.stderr
    assert "Traceback" not in r.stderr
