"""The daemon as systemd runs it: a separate process, a fake NOTIFY_SOCKET, signals,
the external mbpoll tool, and the unit file checked by systemd-analyze."""
import os
import re
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from drivers.modbus_map import MAP_VERSION
from drivers.published_values import StatusBits
from tests.daemon_helpers import CLI, Emulator

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_config(path: Path, board: str, port: int, **extra: str) -> None:
    lines = [
        "[serial]", f'port = "{board}"', "stale_after_ms = 200", "lost_after_ms = 1000",
        "[modbus]", f"port = {port}", f'word_order = "{extra.get("word_order", "ABCD")}"',
        "[can]", 'interface = "virtual"', 'channel = "svc-test"',
        "[state]", f'path = "{path.parent / "state.json"}"',
        "[estimator]", "start_at_rest = true",  # the emulated board starts at rest
    ]
    path.write_text("\n".join(lines) + "\n")


class NotifySocket:
    def __init__(self, tmp_path: Path):
        self.path = str(tmp_path / "notify.sock")
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.messages: list[str] = []

    def wait_for(self, text: str, timeout_s: float) -> float:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                msg = self.sock.recv(4096).decode()
            except TimeoutError:
                break
            self.messages.append(msg)
            if text in msg:
                return time.monotonic()
        raise AssertionError(f"no {text!r} within {timeout_s} s; got {self.messages}")


def mbpoll(port: int, *args: str) -> str:
    r = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-1", "-0", *args, "127.0.0.1"],
                       capture_output=True, text=True, timeout=20)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def mbpoll_values(out: str) -> dict[int, str]:
    return {int(a): v for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", out, re.M)}


def wait_for_valid(port: int, timeout_s: float = 30.0) -> int:
    """Poll the status register until VALID: after a start the estimator holds its
    outputs (HOLDING, BIAS_ESTIMATING) until it has measured the bias at the first
    standstill, which on a slow machine ends well after READY and the first watchdog."""
    deadline = time.monotonic() + timeout_s
    status = None
    while time.monotonic() < deadline:
        status = int(mbpoll_values(mbpoll(port, "-t", "3", "-r", "1", "-c", "1"))[1])
        if status & StatusBits.VALID:
            return status
        time.sleep(0.2)
    raise AssertionError(f"no VALID within {timeout_s} s; last status {status!r}")


def test_ready_watchdog_reload_and_clean_stop(tmp_path):
    assert shutil.which("mbpoll"), "mbpoll missing: run scripts/setup.sh --test"
    emu = Emulator(tmp_path, "--strokes", "2")
    port = free_port()
    cfg = tmp_path / "gw.toml"
    write_config(cfg, str(emu.link), port)
    notify = NotifySocket(tmp_path)
    env = {**os.environ, "NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "400000"}
    daemon = subprocess.Popen([*CLI, "run", "--config", str(cfg)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        notify.wait_for("READY=1", 30)
        notify.wait_for("WATCHDOG=1", 5)  # samples flow, so the watchdog is fed

        # the external Modbus tool reads the running daemon (0-based addresses with -0)
        wait_for_valid(port)
        out = mbpoll(port, "-t", "3", "-r", "0", "-c", "2")
        values = mbpoll_values(out)
        assert values[0] == str(MAP_VERSION)
        assert int(values[1]) & StatusBits.VALID
        out = mbpoll(port, "-t", "3:float", "-B", "-r", "4", "-c", "1")
        position = float(mbpoll_values(out)[4])
        assert -0.02 < position < 0.32

        # SIGHUP with a bad file: refused, the daemon keeps serving
        cfg.write_text(cfg.read_text() + "\n[modbus]\nbogus = 1\n")
        daemon.send_signal(signal.SIGHUP)
        notify.wait_for("READY=1", 5)
        wait_for_valid(port, 10)
        # SIGHUP with a good file: applied, CONFIG_RELOADED shows it
        write_config(cfg, str(emu.link), port, word_order="CDAB")
        daemon.send_signal(signal.SIGHUP)
        notify.wait_for("RELOADING=1", 5)
        notify.wait_for("READY=1", 10)
        time.sleep(0.3)
        status = int(mbpoll_values(mbpoll(port, "-t", "3", "-r", "1", "-c", "1"))[1])
        assert status & StatusBits.CONFIG_RELOADED
        out = mbpoll(port, "-t", "3:float", "-r", "4", "-c", "1")  # mbpoll's default float order is CDAB
        assert -0.02 < float(mbpoll_values(out)[4]) < 0.32

        t_term = time.monotonic()
        daemon.send_signal(signal.SIGTERM)
        stopped = notify.wait_for("STOPPING=1", 2)
        daemon.wait(timeout=2)
        assert time.monotonic() - t_term < 2.0
        assert stopped - t_term < 2.0
        assert daemon.returncode == 0, daemon.stderr.read()
        err = daemon.stderr.read()
        assert "reload refused" in err and "not valid TOML" in err, err
    finally:
        if daemon.poll() is None:
            daemon.kill()
        emu.stop()


def test_watchdog_stops_when_samples_stop(tmp_path):
    emu = Emulator(tmp_path, "--strokes", "2")
    cfg = tmp_path / "gw.toml"
    write_config(cfg, str(emu.link), free_port())
    notify = NotifySocket(tmp_path)
    env = {**os.environ, "NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "200000"}
    daemon = subprocess.Popen([*CLI, "run", "--config", str(cfg)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        notify.wait_for("READY=1", 30)
        notify.wait_for("WATCHDOG=1", 5)
        emu.proc.send_signal(signal.SIGSTOP)  # the board hangs
        time.sleep(1.5)  # lost_after_ms = 1000: pings sent until then are legitimate
        notify.sock.setblocking(False)
        with pytest.raises(BlockingIOError):
            while True:
                notify.sock.recv(4096)  # drain what was queued before the board went silent
        notify.sock.setblocking(True)
        notify.sock.settimeout(1.0)
        with pytest.raises(socket.timeout):
            while True:
                msg = notify.sock.recv(4096).decode()
                assert "WATCHDOG" not in msg, "watchdog fed although no samples flow"
        emu.proc.send_signal(signal.SIGCONT)
        notify.wait_for("WATCHDOG=1", 5)
    finally:
        emu.proc.send_signal(signal.SIGCONT)
        daemon.terminate()
        daemon.wait(timeout=5)
        emu.stop()


def test_bad_config_is_one_line_exit_2(tmp_path):
    cfg = tmp_path / "gw.toml"
    cfg.write_text("[modbus]\nport = 99999\n")
    r = subprocess.run([*CLI, "run", "--config", str(cfg)], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert r.stderr.strip() == f"adxlgw run: error: {cfg}: modbus.port = 99999 must be ≤ 65535"
    r = subprocess.run([*CLI, "run", "--modbus-port", "-5"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "modbus.port = -5 must be ≥ 0" in r.stderr


def test_restart_keeps_position_but_flags_it_not_referenced(tmp_path):
    emu = Emulator(tmp_path, "--strokes", "2")
    port = free_port()
    cfg = tmp_path / "gw.toml"
    write_config(cfg, str(emu.link), port)
    try:
        for _attempt in range(2):
            daemon = subprocess.Popen([*CLI, "run", "--config", str(cfg)],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                r = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(port), "-1", "-0", "-t", "3", "-r", "1",
                                    "-c", "1", "127.0.0.1"], capture_output=True, text=True)
                if r.returncode == 0 and int(mbpoll_values(r.stdout)[1]) & StatusBits.VALID:
                    break
                time.sleep(0.2)
            status = int(mbpoll_values(r.stdout)[1])
            assert status & StatusBits.NOT_REFERENCED  # after every start
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=5)
        state = (tmp_path / "state.json").read_text()
        assert '"last_position_m"' in state
    finally:
        emu.stop()


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_unit_file_passes_systemd_analyze_verify(tmp_path):
    # the unit as `adxlgw install-files` installs it: ExecStart names this venv's adxlgw
    r = subprocess.run([*CLI, "install-files", "--root", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    path = tmp_path / "etc/systemd/system/adxl-gateway.service"
    r = subprocess.run(["systemd-analyze", "verify", str(path)], capture_output=True, text=True, timeout=60)
    problems = [line for line in (r.stdout + r.stderr).splitlines()
                if "adxl-gateway.service" in line]
    assert r.returncode == 0 and not problems, r.stdout + r.stderr
    # the hardening score, offline (docs/daemon.md quotes it): "OK" or better
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--no-pager", str(path)],
                       capture_output=True, text=True, timeout=60)
    score = re.search(r"Overall exposure level for adxl-gateway.service: (\d+\.\d) (\w+)", r.stdout)
    assert score, r.stdout + r.stderr
    assert float(score[1]) <= 3.0 and score[2] in ("OK", "SAFE"), score[0]
