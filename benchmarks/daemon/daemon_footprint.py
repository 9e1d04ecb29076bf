"""The daemon's install size and its start to the first Modbus answer, side by side.

    .venv/bin/python -m benchmarks.daemon.daemon_footprint --venv today=/tmp/full --venv slim=/tmp/slim [--runs 5]

Each --venv is a virtual environment with adxl-gateway installed the way a user would
(`pip install -c constraints.txt PATH`, not editable). Per venv:

- install size: its site-packages less those of an empty venv of the same Python (pip
  and setuptools): what `pip install adxl-gateway` put there, MB;
- spawn → first Modbus answer of its `adxlgw run` (Modbus TCP on a free port, CAN off, a
  board port that is a pty nobody writes: the daemon serves while it waits for samples),
  from its own working directory in /tmp (no source tree on the path), wall time and the
  daemon's CPU time (user + system, /proc) at that moment;
- spawn → READY: systemd's notification (sd_notify READY=1 on a socket of ours in
  $NOTIFY_SOCKET), sent once the whole daemon is up — the estimator loaded, the board's
  port open, every wire started. A daemon that answers Modbus before that answers "nothing
  measured yet" (status BOARD_LOST, NOT_REFERENCED) until then.

One warm-up start per venv (numba's cache, the page cache; it waits for READY, so the
compiled code is on disk), then the venvs take turns, `--runs` each.

Numbers move with the host's load (printed): compare the venvs of one run.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.daemon.service_timing import first_answer, free_port
from drivers.pty_port import PtyPort

ROOT = Path(__file__).resolve().parents[2]

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def tree_mb(path: Path) -> float:
    total = 0
    for dirpath, _, files in os.walk(path):
        for name in files:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(dirpath, name)).st_size
    return total / 1e6


def site_packages(venv: Path) -> Path:
    (found,) = venv.glob("lib/python3*/site-packages")
    return found


def install_mb(venv: Path, empty: Path) -> float:
    return tree_mb(site_packages(venv)) - tree_mb(site_packages(empty))


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime


def ready_at(notify: socket.socket, deadline: float) -> float | None:
    """Monotonic time the daemon's READY=1 came on `notify`."""
    while (left := deadline - time.monotonic()) > 0:
        notify.settimeout(left)
        try:
            message = notify.recv(4096)
        except TimeoutError:
            return None
        if message.startswith(b"READY=1"):
            return time.monotonic()
    return None


def one_start(venv: Path, tmp: Path) -> tuple[float, float, float]:
    port = free_port()
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify_path = tmp / f"notify-{port}"
    notify.bind(str(notify_path))
    pty = PtyPort(tmp / f"board-{port}")
    config = tmp / f"gw-{port}.toml"
    config.write_text(f'[serial]\nport = "{pty.link}"\n[modbus]\nport = {port}\n[can]\nenabled = false\n'
                      f'[state]\npath = "{tmp / f"state-{port}.json"}"\n[service]\nlog_level = "warning"\n')
    t0 = time.monotonic()
    proc = subprocess.Popen([str(venv / "bin" / "adxlgw"), "run", "--config", str(config)], cwd=tmp,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "NOTIFY_SOCKET": str(notify_path)})
    try:
        answered = first_answer(port, t0 + 120)
        cpu = cpu_s(proc.pid)
        if answered is None:
            raise SystemExit(f"{venv}: the daemon never answered on Modbus: {proc.stderr.read().decode()[-500:]}")
        ready = ready_at(notify, t0 + 300)
        if ready is None:
            raise SystemExit(f"{venv}: the daemon never said READY: {proc.stderr.read().decode()[-500:]}")
        return answered - t0, cpu, ready - t0
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        pty.close(remove_link=True)
        notify.close()
        notify_path.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--venv", action="append", required=True, metavar="NAME=PATH")
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    venvs = {name: Path(path) for name, path in (v.split("=", 1) for v in args.venv)}
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-footprint-"))
    try:
        empty = tmp / "empty-venv"
        subprocess.run([sys.executable, "-m", "venv", str(empty)], check=True)
        load_before = os.getloadavg()
        for venv in venvs.values():
            one_start(venv, tmp)  # warm-up, not counted
        times: dict[str, list[tuple[float, float, float]]] = {name: [] for name in venvs}
        for _ in range(args.runs):
            for name, venv in venvs.items():
                times[name].append(one_start(venv, tmp))
        load_after = os.getloadavg()
        harness.stamp("benchmarks.daemon.daemon_footprint")
        print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
        print("| venv | install, MB | spawn → first Modbus answer, s (median, range) | daemon CPU by then, s (median) "
              "| spawn → READY, s (median, range) |")
        print("| --- | --- | --- | --- | --- |")
        for name, venv in venvs.items():
            wall = [w for w, _, _ in times[name]]
            cpu = [c for _, c, _ in times[name]]
            ready = [r for _, _, r in times[name]]
            print(f"| {name} | {install_mb(venv, empty):.0f} | {statistics.median(wall):.2f} "
                  f"({min(wall):.2f}–{max(wall):.2f}) | {statistics.median(cpu):.2f} "
                  f"| {statistics.median(ready):.2f} ({min(ready):.2f}–{max(ready):.2f}) |")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the empty venv, configs, state files


if __name__ == "__main__":
    main()
