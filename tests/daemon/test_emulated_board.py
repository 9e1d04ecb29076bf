"""No orphans: the emulated board process ends with the process that started it, even
when that one is killed with SIGKILL before it ever opened the board's port (the board
would otherwise wait for a reader forever)."""
import os
import signal
import subprocess
import sys
import time

from tests.daemon_helpers import alive

PARENT = """
import asyncio, sys, time
from gateway.daemon.emulated_board import EmulatedBoard

async def main():
    board = EmulatedBoard()
    await board.start()
    print(board.proc.pid, flush=True)
    time.sleep(600)  # never opens the port, never stops the board: only SIGKILL ends this

asyncio.run(main())
"""


def test_the_board_dies_with_a_parent_killed_by_sigkill():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    board = int(parent.stdout.readline())
    time.sleep(0.5)
    assert alive(board)
    parent.kill()
    parent.wait(timeout=30)
    deadline = time.monotonic() + 10
    while alive(board) and time.monotonic() < deadline:
        time.sleep(0.05)
    survived = alive(board)
    if survived:
        os.kill(board, signal.SIGKILL)  # the orphan the test found must not outlive it
    assert not survived, f"emulated board {board} outlived its parent"


def test_a_board_that_cannot_start_is_a_device_error_not_a_wait():
    """No time limit of its own, but a child that dies ends the wait at once."""
    import asyncio

    import pytest

    from gateway.daemon.emulated_board import EmulatedBoard
    from gateway.errors import DeviceError

    async def start():
        board = EmulatedBoard(extra_args=("--strokes", "0"))  # refused by emulate's own arguments
        try:
            await board.start()
        finally:
            await board.stop()

    with pytest.raises(DeviceError, match="the emulated board did not start"):
        asyncio.run(asyncio.wait_for(start(), timeout=120))


def test_sigterm_ends_the_board_cleanly_while_it_watches_stdin(tmp_path):
    """systemd's stop sends SIGTERM to the whole cgroup, the board child included. Its
    stdin watcher (a daemon thread) used to sit in sys.stdin.buffer.read1() holding the
    BufferedReader's lock, so interpreter shutdown waited ~1 s for that lock and then
    aborted ("Fatal Python error: _enter_buffered_busy", SIGABRT): 1.2 s per stop on this
    machine, ten times that under qemu's emulated CPU."""
    board = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "emulate", "--loop", "--no-wait", "--exit-with-stdin",
         "--link", str(tmp_path / "board")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert board.stdout.readline(), board.stderr.read()
        time.sleep(0.5)
        board.terminate()
        board.wait(timeout=60)  # stdin still open: communicate() would close it, and EOF ends the watcher
        err = board.stderr.read()
    finally:
        if board.poll() is None:
            board.kill()
            board.wait()
    assert board.returncode == 0, err
    assert "Fatal Python error" not in err, err


def test_a_gateway_killed_by_sigkill_leaves_a_board_directory_the_next_one_removes(tmp_path, monkeypatch):
    """SIGKILL runs no cleanup: the board's private directory stays behind in the temp dir.
    Whose owner is gone is known for sure (its flock is free): the next emulated board
    removes those, and never the directory of a gateway that lives."""
    import asyncio
    import tempfile

    from gateway.daemon.emulated_board import EmulatedBoard, remove_stale_board_dirs

    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "TMPDIR": str(tmp_path)})
    board = int(parent.stdout.readline())
    parent.kill()
    parent.wait(timeout=30)
    deadline = time.monotonic() + 30
    while alive(board) and time.monotonic() < deadline:
        time.sleep(0.05)
    (left,) = tmp_path.glob("adxlgw-board-*")  # what the killed gateway left

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    living = EmulatedBoard()  # holds its directory's lock (its child not started)
    try:
        assert remove_stale_board_dirs(str(tmp_path), min_age_s=0) == [left]
        assert not left.exists() and living.link.parent.is_dir()
    finally:
        asyncio.run(living.stop())
    assert list(tmp_path.glob("adxlgw-board-*")) == []
