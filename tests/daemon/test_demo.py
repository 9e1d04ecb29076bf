"""`adxlgw demo` as a user starts it: the emulated board chosen on purpose, nothing kept
between runs, and no board process left behind when the demo is killed."""
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.daemon_helpers import alive

pytestmark = pytest.mark.slow
CLI = [sys.executable, "-m", "gateway.cli"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def children(pid: int) -> list[int]:
    with open(f"/proc/{pid}/task/{pid}/children") as fh:
        return [int(p) for p in fh.read().split()]


class Demo:
    """The demo in its own process, with a home, a state home and a temp dir of its own."""

    def __init__(self, tmp_path: Path):
        self.dirs = {name: tmp_path / name for name in ("home", "state", "tmp")}
        for d in self.dirs.values():
            d.mkdir(exist_ok=True)
        env = {**os.environ, "HOME": str(self.dirs["home"]), "XDG_STATE_HOME": str(self.dirs["state"]),
               "TMPDIR": str(self.dirs["tmp"]), "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([*CLI, "demo", "--modbus-port", str(free_port())], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def wait_for_view(self, timeout_s: float = 60, board_up: bool = False) -> str:
        """The first line of the live view (off a terminal: one plain line per draw); with
        `board_up`, the first once the emulated board runs (the view draws from the moment
        the estimator is loaded, while the board's process may still be starting)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if not line:
                break
            if line.startswith("position") and not (board_up and "board not open yet" in line):
                return line
        self.proc.kill()
        raise AssertionError(f"no view line; stderr: {self.proc.communicate()[1]}")

    def board_pid(self) -> int:
        (pid,) = [p for p in children(self.proc.pid)
                  if b"emulate" in Path(f"/proc/{p}/cmdline").read_bytes()]
        return pid


def test_demo_runs_the_emulated_board_and_keeps_nothing(tmp_path):
    for _ in range(2):  # the second run finds nothing of the first
        demo = Demo(tmp_path)
        line = demo.wait_for_view()
        assert "board " in line and "can virtual:adxlgw-demo" in line
        assert list(demo.dirs["tmp"].glob("adxlgw-demo-*/"))  # its state lives here while it runs
        demo.proc.send_signal(signal.SIGINT)
        _, err = demo.proc.communicate(timeout=30)
        assert demo.proc.returncode == 130, err  # interrupted (README, exit codes)
        assert "serial.port: the built-in emulated board: every value is simulated" in err
        assert "Traceback" not in err
        for name in ("home", "state", "tmp"):
            assert list(demo.dirs[name].iterdir()) == [], f"the demo left {list(demo.dirs[name].iterdir())}"


def test_a_killed_demo_takes_its_board_with_it(tmp_path):
    demo = Demo(tmp_path)
    demo.wait_for_view(board_up=True)
    board = demo.board_pid()
    assert alive(board)
    demo.proc.kill()  # SIGKILL: no handler runs, no cleanup code
    demo.proc.communicate(timeout=30)
    deadline = time.monotonic() + 10
    while alive(board) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not alive(board), f"emulated board {board} outlived its parent"
    # its state directory stays (no cleanup ran); the next demo removes it, its owner gone
    import tempfile

    from gateway.commands.demo import DEMO_DIR_PREFIX
    from gateway.owned_tempdir import STALE_AFTER_S, OwnedTempDir

    (left,) = demo.dirs["tmp"].glob(f"{DEMO_DIR_PREFIX}*")
    old = time.time() - 2 * STALE_AFTER_S  # older than a directory a starting demo may not have locked yet
    os.utime(left, (old, old))
    saved, tempfile.tempdir = tempfile.tempdir, str(demo.dirs["tmp"])
    try:
        with OwnedTempDir(DEMO_DIR_PREFIX):  # what the next demo starts with
            assert not left.exists()
    finally:
        tempfile.tempdir = saved
