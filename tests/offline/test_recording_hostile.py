"""Files that must not crash the commands (issue 16) or be half read or half written (issue 17):
each gives exit 2 and one line naming file, line or row, and column; or, where the file can
still be used, the problem is counted and said."""
import os
import subprocess
import sys

import numpy as np
import pytest

from gateway.errors import RecordingError
from gateway.offline.recording import open_recording, read_recording, to_acceleration, write_recording
from gateway.offline.recording import sources as reader  # the reader: its block sizes are patched here
from testing import hostile_files as hostile
from testing.hostile_files import write_raw


def adxlgw(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gateway.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def one_line_exit_2(r, *fragments):
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    for f in fragments:
        assert f in lines[0], lines[0]


@pytest.fixture(scope="module")
def sim_columns():
    return hostile.simulated_run()


def test_truncated_csv_names_the_cut_line_and_writes_nothing(tmp_path, sim_columns):
    path = hostile.truncated(tmp_path / "r.csv", sim_columns)  # a logger killed mid-row
    n_lines = path.read_bytes().count(b"\n") + 1
    out = tmp_path / "e.csv"
    r = adxlgw("estimate", path, "--out", out)
    one_line_exit_2(r, f"r.csv:{n_lines}:", "cells, the header has", "truncated")
    assert not out.exists() and os.listdir(tmp_path) == ["r.csv"]


def test_column_changing_type_deep_in_the_file_names_line_and_column(tmp_path, sim_columns, monkeypatch):
    path = write_raw(tmp_path / "r.csv", sim_columns)
    lines = path.read_text().splitlines()
    k = len(lines) - 100
    cells = lines[k].split(",")
    cells[2] = "OVERFLOW"
    lines[k] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    header = next(line for line in lines if not line.startswith("#")).split(",")
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    assert str(info.value) == f"{path}:{k + 1}: column {header[2]!r}: 'OVERFLOW' is not a number"
    monkeypatch.setattr(reader, "BLOCK_BYTES", 3000)  # the same in a later block of many
    with pytest.raises(RecordingError) as info2:
        read_recording(path)
    assert str(info2.value) == str(info.value)
    # the streamed estimate: no output left behind
    out = tmp_path / "e.csv"
    r = adxlgw("estimate", path, "--out", out)
    one_line_exit_2(r, f"r.csv:{k + 1}: column {header[2]!r}")
    assert not out.exists() and sorted(os.listdir(tmp_path)) == ["r.csv"]


def test_non_utf8_is_named_with_its_byte_offset(tmp_path, sim_columns):
    path = write_raw(tmp_path / "r.csv", sim_columns)
    data = bytearray(path.read_bytes())
    comment = b"# note=caf\xe9\n"
    data[0:0] = comment
    path.write_bytes(bytes(data))
    for command in (("estimate", path, "--out", tmp_path / "e.csv"), ("diagnose", path),
                    ("fit-drift", path, "--plot", tmp_path / "p.png")):
        r = adxlgw(*command)
        one_line_exit_2(r, "r.csv:1:", "not UTF-8", "byte offset 10")
    # deep in the data
    path = hostile.non_utf8_in_the_data(tmp_path / "s.csv", sim_columns, from_end=50)
    bad = path.read_bytes()
    at = len(bad) - 50
    line = bad[:at].count(b"\n") + 1
    with pytest.raises(RecordingError, match=f"s.csv:{line}: not UTF-8 text .* at byte offset {at}"):
        read_recording(path)


def test_a_field_over_131072_characters_is_refused_by_the_line_limit(tmp_path):
    path = hostile.long_field(tmp_path / "r.csv")
    r = adxlgw("estimate", path, "--out", tmp_path / "e.csv")
    one_line_exit_2(r, "r.csv:3:", f"longer than {reader.MAX_LINE_BYTES} bytes")
    # the same as the file's last line, cut without its newline (a tail once not measured)
    r = adxlgw("diagnose", hostile.long_field(tmp_path / "r.csv", last_line=True))
    one_line_exit_2(r, "r.csv:3:", f"line of {hostile.LONG_FIELD_CHARS + 4} bytes: longer than")
    path.write_text("t_s,acc_x_mps2," + "x" * 140_000 + "\n0,1,2\n")
    r = adxlgw("diagnose", path)
    one_line_exit_2(r, "r.csv:1:", "longer than")


def test_seq_counting_down_or_repeating_is_counted_not_a_blow_up(tmp_path, sim_columns):
    n = sim_columns[1]["seq"].size
    down = hostile.seq_counting_down(tmp_path / "down.csv", sim_columns)
    same = hostile.seq_repeating(tmp_path / "same.csv", sim_columns)
    s = to_acceleration(read_recording(down))
    assert s.lost_before.sum() == 0 and s.report.sequence.backwards == n - 1
    assert to_acceleration(read_recording(same)).report.sequence.repeats == n - 1
    r = adxlgw("estimate", down, "--out", tmp_path / "e.csv")
    assert r.returncode == 0, r.stderr
    assert f"seq steps backwards {n - 1} times (first at sample 2)" in r.stderr
    # wraps are not problems; gaps are losses
    seq = (65530 + np.arange(n)) % 65536
    seq[100:] += 3
    seq %= 65536
    s = to_acceleration(read_recording(write_raw(tmp_path / "wrap.csv", sim_columns, seq=seq)))
    rep = s.report.sequence
    assert (rep.wraps, rep.gaps, rep.lost, rep.repeats, rep.backwards) == (1, 1, 3, 0, 0)
    assert s.report.warnings() == []


def test_seq_claiming_more_losses_than_a_board_can_is_refused(tmp_path, sim_columns):
    n = sim_columns[1]["seq"].size
    path = write_raw(tmp_path / "r.csv", sim_columns, seq=(np.arange(n) * 30000) % 65536)
    r = adxlgw("diagnose", path)
    one_line_exit_2(r, "r.csv:", "samples were lost for")


def test_impossible_samples_are_flagged_invalid_not_integrated(tmp_path):
    path = hostile.impossible_samples(tmp_path / "r.csv", {2500: 1e300, 2600: -5e3}, n=4000)
    s = to_acceleration(read_recording(path))
    assert not s.valid[2500] and not s.valid[2600] and s.valid.sum() == 4000 - 2
    assert s.report.impossible == 2
    out = tmp_path / "e.csv"
    r = adxlgw("estimate", path, "--out", out)
    assert r.returncode == 0, r.stderr
    assert "2 samples beyond ±1000 m/s²" in r.stderr
    pos = np.genfromtxt(out, delimiter=",", names=True)["pos_m"]
    assert np.all(np.abs(pos) < 1.0)
    # raw form: beyond 1.5 × the ADXL202's ±2 g (a duty cycle near 0 or 1)
    seq = np.arange(5)
    rec = {"seq": seq, "t1x": np.array([900, 1700, 100, 922, 921]), "t1y": np.full(5, 921),
           "t2": np.full(5, 1843)}
    write_recording(tmp_path / "raw.csv", {"tick_hz": "921600"}, rec)
    s = to_acceleration(read_recording(tmp_path / "raw.csv"))
    assert s.valid.tolist() == [True, False, False, True, True] and s.report.impossible == 2


def test_damaged_parquet_is_one_line(tmp_path, sim_columns):
    path = write_raw(tmp_path / "r.parquet", sim_columns)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    for command in (("estimate", path, "--out", tmp_path / "e.csv"), ("diagnose", path)):
        one_line_exit_2(adxlgw(*command), "r.parquet:", "not a complete Parquet file")
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"t_s": [0.0, 0.1], "acc_x_mps2": ["1", "2"]}), tmp_path / "s.parquet")
    with pytest.raises(RecordingError, match="column 'acc_x_mps2': has type string, not a number"):
        open_recording(tmp_path / "s.parquet")
    pq.write_table(pa.table({"t_s": [0.0, 0.2, 0.1], "acc_x_mps2": [1.0, 2.0, 3.0]}), tmp_path / "b.parquet")
    with pytest.raises(RecordingError, match=r"b.parquet: row 3: column 't_s': sample times must increase"):
        read_recording(tmp_path / "b.parquet")


def test_smoothed_refuses_what_the_machine_cannot_hold(tmp_path, sim_columns):
    path = write_raw(tmp_path / "r.csv", sim_columns)
    # a sparse file: a valid head, then 2 TB of hole (no disk used): ~20 G samples claimed
    with open(path, "r+b") as fh:
        fh.truncate(2 << 40)
    r = adxlgw("estimate", path, "--method", "smoothed", "--out", tmp_path / "e.csv")
    one_line_exit_2(r, "r.csv: the smoothed estimate (", "bytes per sample) needs about",
                    "GB of memory, the machine has")
    r = adxlgw("diagnose", path)
    one_line_exit_2(r, "r.csv: reading the whole recording needs about")


def test_a_refused_file_exits_2_every_time_not_sometimes_134(tmp_path, sim_columns):
    # pyarrow's thread pool once aborted the interpreter's exit after such an error in
    # about one run of three (exit 134, "terminate called without an active exception")
    n = sim_columns[1]["seq"].size
    for name in ("r.csv", "r.parquet"):
        path = write_raw(tmp_path / name, sim_columns, seq=(np.arange(n) * 30000) % 65536)
        for _ in range(4):
            one_line_exit_2(adxlgw("estimate", path, "--method", "smoothed", "--out", tmp_path / "e.csv"),
                            "samples were lost for")


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_a_rest_without_noise_is_refused_in_one_line_not_a_traceback(tmp_path, method):
    # the acceleration form's noise settings come from its initial rest; a noise-free one
    # (a synthetic file) raised from the settings with a traceback, exit 1
    path = hostile.quiet_rest(tmp_path / "r.csv", step_mg=None)
    r = adxlgw("estimate", path, "--method", method, "--out", tmp_path / "e.csv")
    one_line_exit_2(r, "r.csv: cannot estimate", "the rest is constant: no noise to measure")
    assert not (tmp_path / "e.csv").exists()
    # the raw form's settings come from the sensor model: the rest's noise is not needed
    r = adxlgw("estimate", path, "--method", method, "--noise-from", "sensor", "--out", tmp_path / "e.csv")
    assert r.returncode == 0, r.stderr
    # diagnose (with the file's reference) falls back to the data-sheet noise and says so
    r = adxlgw("diagnose", path)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "the rest is constant" in r.stderr and "data-sheet values are used" in r.stderr


@pytest.mark.parametrize("method", ["realtime", "smoothed"])
def test_a_rest_quantised_coarser_than_its_noise_is_a_rest(tmp_path, method):
    # 2 mg of noise quantised to 10 mg: the 2 s rest is one value with a rare one-step
    # flicker, which was taken for motion ("the recording moves after 0.211 s", exit 2)
    path = hostile.quiet_rest(tmp_path / "q.csv", step_mg=10.0)
    r = adxlgw("estimate", path, "--method", method, "--out", tmp_path / "e.csv")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert (tmp_path / "e.csv").exists()


def test_a_file_of_one_sample_is_refused_in_one_line(tmp_path):
    # the streamed estimate took its settings from a first chunk of one row: the sample
    # period of one sample was NaN, a traceback (exit 1)
    path = tmp_path / "r.csv"
    write_recording(path, {"axis": "x"}, {"t_s": np.zeros(1), "acc_x_mps2": np.ones(1)})
    r = adxlgw("estimate", path, "--out", tmp_path / "e.csv")
    one_line_exit_2(r, "r.csv: cannot estimate (realtime): only 1 sample")
    assert not (tmp_path / "e.csv").exists()


@pytest.mark.parametrize("plot, message", [
    ("missing/p.png", "no directory"),
    ("p.xlsx", "not a figure's extension"),
])
def test_a_plot_it_cannot_write_is_refused_before_the_work(tmp_path, sim_columns, plot, message):
    """A long estimate or fit that only then finds it cannot save its figure loses the run:
    the plot's path is checked first (a recording that does not even exist shows it)."""
    path = write_raw(tmp_path / "r.csv", sim_columns)
    out = ("--out", tmp_path / "e.csv")
    for command in (("estimate", path, *out, "--plot", tmp_path / plot), ("fit-drift", path, "--plot", tmp_path / plot),
                    ("estimate", tmp_path / "absent.csv", *out, "--plot", tmp_path / plot)):
        one_line_exit_2(adxlgw(*command), f"--plot {tmp_path / plot}: {message}")
