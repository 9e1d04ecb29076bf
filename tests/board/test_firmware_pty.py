"""scripts/board-in-ucsim read by `adxlgw record` through a pty, as a board is read.

10 s of board time (the relay paces the frames to it, so the test lasts at least that
long; s51 runs ahead on its own core). No timing asserts: the counts are the check.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gateway.offline.recording import read_recording

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "gateway.cli"]
BOARD_S = 10.0


def test_adxlgw_record_reads_the_firmware_on_a_pty_without_loss(tmp_path):
    link = tmp_path / "board"
    board = subprocess.Popen([str(ROOT / "scripts/board-in-ucsim"), "--link", str(link), "--seconds", str(BOARD_S),
                              "--seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = board.stdout.readline().strip()
        assert first == str(link), board.stderr.read()
        out = tmp_path / "rec.csv"
        rec = subprocess.run([*CLI, "record", "--port", str(link), "--out", str(out), "--once"],
                             capture_output=True, text=True, timeout=600)
        _, board_err = board.communicate(timeout=600)
    finally:
        board.kill()
    assert board.returncode == 0, board_err
    # the recorder ends when the board's port goes away (--once: exit 3, port lost)
    assert rec.returncode == 3, rec.stderr
    assert "crc errors 0" in rec.stderr and "samples lost 0" in rec.stderr and "bytes skipped 0" in rec.stderr
    sent = int(board_err.split("sent ")[1].split(" samples")[0])
    recording = read_recording(out)
    c = recording.columns
    assert recording.metadata["tick_hz"] == "921600"
    assert len(recording) == sent
    assert np.all(np.diff(c["seq"]) == 1) and c["seq"][0] == 0
    board_time_s = c["t2"].sum() / 921_600
    assert board_time_s > BOARD_S - 0.2  # all but the start-up
    assert "idle" in board_err and "machine cycles per sample" in board_err
