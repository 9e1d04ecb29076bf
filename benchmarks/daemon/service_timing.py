"""How long `adxlgw run` takes to start, to answer, to ping the watchdog and to stop.

    .venv/bin/python -m benchmarks.daemon.service_timing [--runs 5]

What systemd and a PLC see of the daemon's lifetime, on this machine's real CPU (the
qemu VM of tests/daemon/test_systemd_vm.py runs the same under emulation, slower). Each run
starts `adxlgw run` (the built-in emulated board, CAN on the virtual bus, Modbus TCP on a
free port, a fresh state file) in its own session, as systemd would: NOTIFY_SOCKET is a
datagram socket this script reads (sd_notify(3)), WATCHDOG_USEC 10 s. Measured per run:

- spawn → first Modbus answer: what a restart after kill -9 costs a PLC before the
  daemon answers again (its first answer already carries the restart's flags);
- spawn → READY=1 (the unit's start; the numba cache is warm after the first run);
- READY → first WATCHDOG=1 (must come well inside WatchdogSec);
- SIGTERM → the daemon and every process of its group gone (what `systemctl stop`
  waits for; polled every 10 ms).

Numbers move with the host's load (printed before and after): compare runs made together.
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness

ROOT = Path(__file__).resolve().parents[2]

WATCHDOG_USEC = 10_000_000
READ_INPUT_ALL = bytes.fromhex("000100000006010400000001")  # MBAP + read 1 input register


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def first_answer(port: int, deadline: float) -> float | None:
    """Monotonic time of the first Modbus answer, polling every 10 ms."""
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2) as conn:
                conn.sendall(READ_INPUT_ALL)
                if conn.recv(64):
                    return time.monotonic()
        except OSError:
            pass
        time.sleep(0.01)
    return None


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def one_run(tmp: Path) -> dict[str, float]:
    port = free_port()
    config = tmp / "gw.toml"
    config.write_text(
        f'[serial]\nport = "emulated"\n[modbus]\nport = {port}\n'
        f'[can]\ninterface = "virtual"\nchannel = "timing-{port}"\n'
        f'[state]\npath = "{tmp / f"state-{port}.json"}"\n[service]\nlog_level = "warning"\n'
    )
    notify_path = tmp / f"notify-{port}"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(notify_path))
    notify.settimeout(0.01)
    env = dict(os.environ, NOTIFY_SOCKET=str(notify_path), WATCHDOG_USEC=str(WATCHDOG_USEC))
    env.pop("WATCHDOG_PID", None)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "run", "--config", str(config)], cwd=ROOT,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, start_new_session=True)
    result: dict[str, float] = {}
    try:
        answered = first_answer(port, t0 + 120)
        if answered is None:
            raise SystemExit(f"the daemon never answered on Modbus: {proc.stderr.read().decode()[-500:]}")
        result["answer_s"] = answered - t0
        ready = watchdog = None
        deadline = time.monotonic() + WATCHDOG_USEC / 1e6 + 30
        while watchdog is None and time.monotonic() < deadline:
            try:
                message = notify.recv(4096).decode()
            except TimeoutError:
                continue
            now = time.monotonic()
            if ready is None and "READY=1" in message.split("\n"):
                ready = now
            elif ready is not None and "WATCHDOG=1" in message.split("\n"):
                watchdog = now
        if ready is None or watchdog is None:
            raise SystemExit("no READY=1 or no WATCHDOG=1 from the daemon")
        result["ready_s"] = ready - t0
        result["watchdog_after_ready_s"] = watchdog - ready
        time.sleep(1.0)
        t_term = time.monotonic()
        os.killpg(proc.pid, signal.SIGTERM)
        while group_alive(proc.pid) and time.monotonic() - t_term < 30:
            proc.poll()  # reap the daemon so that the group can empty
            time.sleep(0.01)
        result["stop_s"] = time.monotonic() - t_term
        if proc.wait(timeout=5) != 0:
            raise SystemExit(f"the daemon stopped with status {proc.returncode}")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        notify.close()
        notify_path.unlink(missing_ok=True)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5, help="starts and stops, after one warm-up start")
    args = ap.parse_args()
    load_before = os.getloadavg()
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-timing-"))
    one_run(tmp)  # warm-up: the numba cache and the page cache, not counted
    runs = [one_run(tmp) for _ in range(args.runs)]
    load_after = os.getloadavg()
    harness.stamp("benchmarks.daemon.service_timing")
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f}; {args.runs} runs after a warm-up")
    labels = {
        "answer_s": "spawn -> first Modbus answer",
        "ready_s": "spawn -> READY=1",
        "watchdog_after_ready_s": f"READY -> first WATCHDOG=1 (WatchdogSec {WATCHDOG_USEC / 1e6:g} s)",
        "stop_s": "SIGTERM -> the whole process group gone",
    }
    for key, label in labels.items():
        values = [r[key] for r in runs]
        print(f"  {label:<48} median {statistics.median(values):6.2f} s   "
              f"range {min(values):.2f}-{max(values):.2f} s")


if __name__ == "__main__":
    main()
