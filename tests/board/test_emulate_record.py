"""The virtual board on a real pty in one process, the recorder in another."""
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from gateway.offline.recording import read_recording, to_acceleration

CLI = [sys.executable, "-m", "gateway.cli"]
LINGER_FOR_A_SLOW_READER_S = 5


def start_emulator(*args):
    proc = subprocess.Popen([*CLI, "emulate", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    path = proc.stdout.readline().strip()
    assert path, proc.stderr.read()
    return proc, path


@pytest.mark.slow
def test_recording_equals_emulated_samples_one_for_one_at_500_per_s(tmp_path):
    strokes, seed = 4, 11
    emu, path = start_emulator("--strokes", strokes, "--seed", seed, "--linger", "1")
    assert os.path.exists(path)
    out = tmp_path / "rec.csv"
    rec = subprocess.run([*CLI, "record", "--port", path, "--out", out, "--once"],
                         capture_output=True, text=True, timeout=120)
    emu.wait(timeout=30)
    emu_err = emu.stderr.read()
    # the recorder ends when the board's port goes away (--once: exit 3, port lost)
    assert rec.returncode == 3, rec.stderr
    assert "record: " in rec.stderr and "crc errors 0" in rec.stderr and "samples lost 0" in rec.stderr
    assert "0 chunks sent with nobody listening; 0 writes cut short" in emu_err

    truth = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=strokes))), seed=seed)
    recording = read_recording(out)
    assert recording.metadata["tick_hz"] == "921600"
    c = recording.columns
    assert len(recording) == len(truth)  # no loss: ~4 400 samples at 500 samples/s, paced in real time
    for name in ("seq", "t1x", "t1y", "t2", "flags"):
        np.testing.assert_array_equal(c[name], getattr(truth, name), err_msg=name)
    # host arrival times show real-time pacing, ~2 ms apart on average
    rate = (len(recording) - 1) / (c["t_host_s"][-1] - c["t_host_s"][0])
    assert rate == pytest.approx(1 / truth.t2.mean() * truth.tick_hz, rel=0.1)
    assert np.all(c["temp_c"][np.isfinite(c["temp_c"])] == 25.0)


def test_record_once_on_a_missing_port_exits_3_with_a_clear_message(tmp_path):
    r = subprocess.run([*CLI, "record", "--port", tmp_path / "no-such-tty", "--out", tmp_path / "r.csv", "--once"],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 3
    assert "no-such-tty" in r.stderr and "No such file or directory" in r.stderr
    assert "Traceback" not in r.stderr


def test_record_without_once_keeps_retrying_until_the_port_appears(tmp_path):
    link = tmp_path / "board"
    # no --duration: a fixed one ran out before a slow machine had the emulator up; the
    # recorder is stopped by SIGTERM (an orderly stop, exit 0) once the board is done
    rec = subprocess.Popen([*CLI, "record", "--port", link, "--out", tmp_path / "r.csv"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(1.0)  # the recorder is retrying: the port does not exist yet
    emu, path = start_emulator("--strokes", 1, "--link", link, "--linger", "2", "--rest-s", "0.5")
    emu.wait(timeout=120)
    rec.terminate()
    out, err = rec.communicate(timeout=60)
    assert rec.returncode == 0, err
    assert "retrying" in err
    recording = read_recording(tmp_path / "r.csv")
    assert len(recording) > 100


def test_emulator_faults_reach_the_decoder_and_are_counted(tmp_path):
    # --fast writes as fast as the recorder reads; the last bytes still sit in the pty when
    # the board is done, and closing it then drops them: --linger gives a recorder slowed by a
    # loaded machine time to read them (0.5 s failed once beside a VM test)
    emu, path = start_emulator("--strokes", 2, "--fast", "--garbage-every", "0.5", "--drop-every", "0.7",
                               "--reset-every", "3", "--linger", LINGER_FOR_A_SLOW_READER_S)
    out = tmp_path / "rec.csv"
    rec = subprocess.run([*CLI, "record", "--port", path, "--out", out, "--once"],
                         capture_output=True, text=True, timeout=120)
    emu.wait(timeout=30)
    err = rec.stderr
    assert "board resets 2" in err  # power-on HELLO + one reset
    lost = int(err.split("samples lost ")[1].split(";")[0])
    assert lost >= 5
    assert "bytes skipped 0" not in err
    # the reset started a second file whose seq restarts at 0
    second = read_recording(tmp_path / "rec.reset1.csv")
    assert second.columns["seq"][0] == 0
    series = to_acceleration(second)
    assert np.all(np.diff(series.t_s) > 0)


def test_the_emulated_boards_rset_sets_its_sensor_period(tmp_path):
    """--rset-kohm 1250: T2 = RSET / 125 MΩ = 10 ms (the part's +0.5 % T2 error on top), so
    100 samples per second of board time, each carrying that period in ticks."""
    emu, path = start_emulator("--scenario", "standstill", "--duration", 2, "--rset-kohm", 1250, "--fast",
                               "--linger", LINGER_FOR_A_SLOW_READER_S)
    out = tmp_path / "rec.csv"
    rec = subprocess.run([*CLI, "record", "--port", path, "--out", out, "--once"],
                         capture_output=True, text=True, timeout=120)
    emu.wait(timeout=30)
    assert rec.returncode == 3, rec.stderr
    c = read_recording(out).columns
    t2_s = c["t2"] / 921600
    assert np.median(t2_s) == pytest.approx(0.010 * 1.005, rel=2e-3)
    assert len(c["t2"]) == pytest.approx(2 / 0.01005, abs=2)


def test_an_rset_outside_the_data_sheets_range_is_refused():
    r = subprocess.run([*CLI, "emulate", "--rset-kohm", "5000"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "RSET must be within 62.5–1250 kΩ" in r.stderr
