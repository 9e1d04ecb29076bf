"""Recordings as CSV and Parquet: the same content both ways, read in chunks like whole,
and the realtime estimate streamed chunk by chunk gives the whole-file numbers."""
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from gateway.core.estimator import estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.estimator_stream import RealtimeChunks
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.offline.recording import (
    acceleration_chunks,
    open_recording,
    read_recording,
    to_acceleration,
    write_recording,
)
from gateway.offline.recording import sources as reader  # the reader: its block sizes are patched here
from tests.pty_helpers import stderr_on_a_pty


def adxlgw(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gateway.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def simulated(path, strokes=3, seed=11):
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=strokes)), seed=seed)
    write_recording(path, {"tick_hz": f"{run.tick_hz:g}", "axis": "x", "source": "simulation",
                           "note": "µ and = kept"}, run.recording_columns())
    return run


def test_csv_to_parquet_to_csv_is_identical(tmp_path):
    simulated(tmp_path / "a.csv")
    rec = read_recording(tmp_path / "a.csv")
    write_recording(tmp_path / "b.parquet", rec.metadata, rec.columns)
    back = read_recording(tmp_path / "b.parquet")
    assert back.metadata == rec.metadata and back.form == "raw"
    write_recording(tmp_path / "c.csv", back.metadata, back.columns)
    assert (tmp_path / "c.csv").read_bytes() == (tmp_path / "a.csv").read_bytes()
    # the metadata is the Parquet file's own key-value metadata, readable by any Parquet tool
    kv = pq.ParquetFile(tmp_path / "b.parquet").schema_arrow.metadata
    assert kv[b"tick_hz"] == rec.metadata["tick_hz"].encode() and kv[b"format"] == b"adxl-recording/1"


def test_missing_values_round_trip_as_empty_cells(tmp_path):
    cols = {"t_s": np.array([0.0, 0.1, 0.2]), "acc_x_mps2": np.array([1.5, np.nan, -2.25]),
            "temp_c": np.array([np.nan, np.nan, 21.0])}
    write_recording(tmp_path / "a.csv", {"axis": "x"}, cols)
    lines = (tmp_path / "a.csv").read_text().splitlines()
    assert lines[2:] == ["t_s,acc_x_mps2,temp_c", "0.0,1.5,", "0.1,,", "0.2,-2.25,21.0"]
    write_recording(tmp_path / "a.parquet", {"axis": "x"}, cols)
    for name in ("a.csv", "a.parquet"):
        rec = read_recording(tmp_path / name)
        for k, v in cols.items():
            np.testing.assert_array_equal(rec.columns[k], v)


def test_chunked_csv_reading_gives_the_whole_file(tmp_path, monkeypatch):
    simulated(tmp_path / "a.csv")
    whole = read_recording(tmp_path / "a.csv")
    monkeypatch.setattr(reader, "BLOCK_BYTES", 4096)  # ~60 rows a block: every boundary case
    chunks = list(open_recording(tmp_path / "a.csv").chunks())
    assert len(chunks) > 20
    for name, col in whole.columns.items():
        np.testing.assert_array_equal(np.concatenate([c[name] for c in chunks]), col)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_streamed_realtime_is_the_whole_file_estimate_bit_for_bit(tmp_path, monkeypatch, suffix):
    path = tmp_path / f"a{suffix}"
    simulated(path, strokes=6)
    monkeypatch.setattr(reader, "BLOCK_BYTES", 50_000)
    monkeypatch.setattr(reader, "PARQUET_BATCH_ROWS", 777)
    series = to_acceleration(read_recording(path))
    settings = from_sensor_model(SensorParams(), axis="x")
    whole = estimate_series(series.t_s, series.acc_mps2, series.valid, method="realtime", settings=settings,
                            lost_before=series.lost_before)
    runner = RealtimeChunks(settings)
    parts = [runner.feed(s.t_s, s.acc_mps2, s.valid, s.lost_before) for s in acceleration_chunks(open_recording(path))]
    assert len(parts) > 3
    assert runner.finish() == whole.notes
    for name, col in whole.columns().items():
        np.testing.assert_array_equal(np.concatenate([p.columns()[name] for p in parts]), col)


def test_streamed_realtime_judges_time_gaps_like_the_whole_file(tmp_path):
    # acceleration form with a gap: lost samples from the time axis, chunk by chunk
    t = np.arange(6000) * 0.002
    t[3000:] += 0.02  # 10 samples missing
    acc = np.random.default_rng(5).normal(0, 0.01, t.size)
    settings = from_sensor_model(SensorParams(), axis="x")
    whole = estimate_series(t, acc, method="realtime", settings=settings)
    runner = RealtimeChunks(settings)
    parts = [runner.feed(t[a:a + 1000], acc[a:a + 1000]) for a in range(0, t.size, 1000)]
    assert runner.finish() == whole.notes and any("10 samples lost" in n for n in whole.notes)
    np.testing.assert_array_equal(np.concatenate([p.pos_m for p in parts]), whole.pos_m)


def test_every_command_reads_parquet_like_csv(tmp_path):
    simulated(tmp_path / "a.csv", strokes=4)
    r = adxlgw("simulate", "--strokes", "4", "--seed", "11", "--out", tmp_path / "b.parquet")
    assert r.returncode == 0, r.stderr
    rec = read_recording(tmp_path / "a.csv")
    write_recording(tmp_path / "a.parquet", rec.metadata, rec.columns)
    outs = {}
    for src in ("a.csv", "a.parquet"):
        for method in ("realtime", "smoothed"):
            out = tmp_path / f"{src}.{method}.csv"
            r = adxlgw("estimate", tmp_path / src, "--method", method, "--out", out)
            assert r.returncode == 0, r.stderr
            outs[src, method] = out.read_bytes()
    assert outs["a.csv", "realtime"] == outs["a.parquet", "realtime"]
    assert outs["a.csv", "smoothed"] == outs["a.parquet", "smoothed"]
    # estimate writes Parquet too: the same columns
    r = adxlgw("estimate", tmp_path / "a.parquet", "--out", tmp_path / "e.parquet")
    assert r.returncode == 0, r.stderr
    table = pq.read_table(tmp_path / "e.parquet")
    assert table.column_names[:4] == ["t_s", "pos_m", "vel_mps", "acc_mps2"]
    r = adxlgw("diagnose", tmp_path / "a.parquet", "--json", tmp_path / "d.json")
    assert r.returncode == 0, r.stderr
    sim = adxlgw("simulate", "--scenario", "standstill", "--duration", "120", "--out", tmp_path / "still.parquet")
    assert sim.returncode == 0, sim.stderr
    r = adxlgw("fit-drift", tmp_path / "still.parquet", "--plot", tmp_path / "d.png")
    assert r.returncode == 0, r.stderr
    assert "C1 =" in r.stdout


def test_streamed_error_summary_is_summarise_errors_in_chunks():
    from gateway.core.evaluation import summarise_errors
    from gateway.core.evaluation_stream import StreamedErrors

    run = simulate(reciprocating_strokes(StrokeSettings(strokes=7, dwell_s=0.25)), seed=2)
    t, ref_pos, ref_vel, ref_acc = run.t_s, run.ref_pos_m, run.ref_vel_mps, run.ref_acc_mps2
    pos = ref_pos + np.random.default_rng(6).normal(0, 1e-3, t.size)
    whole = summarise_errors(t, pos, ref_pos, ref_vel, ref_acc)
    assert len(whole.stops) == 7  # the initial rest is not a stop
    rng = np.random.default_rng(7)
    # chunk edges everywhere, also at the first and last sample of every rest run
    still = (np.abs(ref_vel) <= 1e-6) & (np.abs(ref_acc) <= 1e-9)
    run_edges = np.flatnonzero(np.diff(still.astype(int))) + 1
    cuts = np.unique(np.concatenate([rng.integers(1, t.size, 40), run_edges, run_edges + 1, [1, t.size - 1]]))
    judge = StreamedErrors()
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [t.size]]), strict=False):
        judge.feed(t[a:b], pos[a:b], ref_pos[a:b], ref_vel[a:b], ref_acc[a:b])
    got = judge.result()
    assert got.stops == whole.stops
    assert got.final_m == whole.final_m and got.moving_max_m == whole.moving_max_m
    assert got.rms_m == pytest.approx(whole.rms_m, rel=1e-12)
    assert got.travelled_m == pytest.approx(whole.travelled_m, rel=1e-12)


def test_record_writer_streams_parquet_like_csv(tmp_path):
    from gateway.offline.recording import RecordingWriter

    names = ["seq", "t1x", "t1y", "t2", "flags", "t_host_s", "temp_c"]
    rows = [{"seq": k % 65536, "t1x": 900 + k % 7, "t1y": 920, "t2": 1843, "flags": 0,
             "t_host_s": 0.002 * k, "temp_c": None if k < 3 else 24.5} for k in range(70_000)]
    for name in ("r.csv", "r.parquet"):
        w = RecordingWriter(tmp_path / name, {"tick_hz": "921600", "source": "board"}, names)
        for row in rows:
            w.write_row(row)
        w.close()
    a, b = read_recording(tmp_path / "r.csv"), read_recording(tmp_path / "r.parquet")
    assert a.metadata == b.metadata and b.metadata["source"] == "board" and len(b) == 70_000
    for n in names:
        np.testing.assert_array_equal(a.columns[n], b.columns[n])
    assert np.isnan(b.columns["temp_c"][:3]).all() and b.columns["temp_c"][3] == 24.5


def test_progress_bar_on_a_terminal_and_quiet_otherwise(tmp_path):
    simulated(tmp_path / "a.csv")
    cmd = [sys.executable, "-m", "gateway.cli", "estimate", str(tmp_path / "a.csv"), "--out", str(tmp_path / "e.csv")]
    quiet = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0 and "%|" not in quiet.stderr and "it/s" not in quiet.stderr
    # stderr on a pseudo-terminal: the bar is drawn there (and cleared when done)
    code, seen = stderr_on_a_pty(cmd)
    assert code == 0
    assert b"estimating" in seen and b"%|" in seen
