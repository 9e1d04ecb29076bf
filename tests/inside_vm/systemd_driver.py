"""Runs as a service under the real systemd of tests/inside_vm/systemd_job.sh and drives
the shipped unit the way an operator does: systemctl start, reload, stop; a Modbus
client on one TCP connection; journalctl -p err; a board that falls silent. Writes what
it saw as JSON (argv[1]); judges nothing itself (no host-side test judges it yet).
"""
from __future__ import annotations

import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import traceback
from pathlib import Path

UNIT = "adxl-gateway"
CONFIG = Path("/etc/adxl-gateway/gateway.toml")


def run(*argv: str, timeout_s: float = 900) -> dict:
    started = time.monotonic()
    r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
    return {"rc": r.returncode, "seconds": round(time.monotonic() - started, 3), "stdout": r.stdout[-4000:],
            "stderr": r.stderr[-4000:]}


def show(*props: str) -> dict[str, str]:
    out = subprocess.run(["systemctl", "show", UNIT, "-p", ",".join(props)], capture_output=True, text=True,
                         timeout=60).stdout
    return dict(line.split("=", 1) for line in out.splitlines() if "=" in line)


def seconds(span: str) -> float:
    """A systemd time span as `systemctl show` prints it ("10s", "1min", "1min 30s")."""
    units = {"min": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6}
    total = 0.0
    for part in span.split():
        number = part.rstrip("abcdefghijklmnopqrstuvwxyz")
        total += float(number) * units[part[len(number):]]
    return total


def wait_for(predicate, timeout_s: float, poll_s: float = 0.5):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(poll_s)
    return None


class ModbusConnection:
    """One TCP connection, kept: read input registers with hand-made MBAP frames (a
    library client would quietly reconnect and hide a dropped connection)."""

    def __init__(self, port: int = 5020):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=20)
        self.tid = 0

    def read_inputs(self, address: int, count: int) -> list[int]:
        self.tid += 1
        self.sock.sendall(struct.pack(">HHHBBHH", self.tid, 0, 6, 1, 4, address, count))
        head = self._exactly(7)
        tid, _, length, _ = struct.unpack(">HHHB", head)
        body = self._exactly(length - 1)
        if tid != self.tid or body[0] != 4:
            raise RuntimeError(f"unexpected reply {head.hex()} {body.hex()}")
        return list(struct.unpack(f">{body[1] // 2}H", body[2:]))

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("the gateway closed the connection")
            data += chunk
        return data


def board_pid(main_pid: int) -> int | None:
    try:
        children = Path(f"/proc/{main_pid}/task/{main_pid}/children").read_text().split()
    except OSError:
        return None
    for pid in children:
        if b"emulate" in Path(f"/proc/{pid}/cmdline").read_bytes():
            return int(pid)
    return None


def main(report_path: Path) -> None:
    from drivers.published_values import StatusBits

    report: dict = {}
    try:
        report["start"] = run("systemctl", "start", UNIT)  # Type=notify: returns at READY=1
        report["start"].update(show("ActiveState", "SubState", "StatusText", "WatchdogUSec", "MainPID",
                                    "TimeoutStartUSec"))
        first = show("WatchdogTimestampMonotonic")["WatchdogTimestampMonotonic"]
        time.sleep(1.2 * seconds(show("WatchdogUSec")["WatchdogUSec"]))  # a daemon that did not ping is restarted
        later = show("WatchdogTimestampMonotonic", "NRestarts", "ActiveState")
        report["watchdog_pings"] = {"first_us": int(first), "later_us": int(later["WatchdogTimestampMonotonic"]),
                                    "restarts": int(later["NRestarts"]), "active": later["ActiveState"]}

        modbus = ModbusConnection()
        wait_for(lambda: modbus.read_inputs(1, 1)[0] & StatusBits.VALID, 60)
        before = modbus.read_inputs(1, 1)[0]
        report["reload"] = run("systemctl", "reload", UNIT)
        time.sleep(3)
        after = modbus.read_inputs(1, 1)[0]  # on the same connection
        report["reload"].update({"status_before": before, "status_after": after,
                                 "config_reloaded_bit": bool(after & StatusBits.CONFIG_RELOADED),
                                 "same_connection": True, "restarts": int(show("NRestarts")["NRestarts"])})

        good = CONFIG.read_text()
        CONFIG.write_text(good + "\n[modbus]\nbogus = 1\n")  # refused, logged as an error
        report["bad_reload"] = run("systemctl", "reload", UNIT)
        time.sleep(3)
        CONFIG.write_text(good)
        report["bad_reload"]["still_serving"] = bool(modbus.read_inputs(1, 1)[0] & StatusBits.VALID)
        report["journal_err"] = run("journalctl", "-p", "err", "-u", UNIT, "-o", "cat", "--no-pager")["stdout"]
        report["journal_info"] = run("journalctl", "-p", "info", "-u", UNIT, "-o", "cat", "--no-pager")["stdout"]
        modbus.sock.close()

        report["stop"] = run("systemctl", "stop", UNIT)
        report["stop"].update(show("ActiveState", "Result"))
        state = Path("/var/lib/adxl-gateway/state.json")
        report["state"] = {"path": str(state), "resolved": str(state.resolve()), "exists": state.exists(),
                           "content": json.loads(state.read_text()) if state.exists() else None}

        report["restart_start"] = run("systemctl", "start", UNIT)
        main_pid = int(show("MainPID")["MainPID"])
        board = wait_for(lambda: board_pid(main_pid), 30)
        report["silent_board"] = {"main_pid": main_pid, "board_pid": board}
        if board:
            wait_for(lambda: modbus_valid(), 60)
            os.kill(board, signal.SIGSTOP)  # the board falls silent: no samples, so no WATCHDOG=1
            stopped_at = time.monotonic()
            restarted = wait_for(lambda: int(show("NRestarts")["NRestarts"]) >= 1, 60)
            report["silent_board"].update({"restarted": bool(restarted),
                                           "seconds": round(time.monotonic() - stopped_at, 1)})
            wait_for(lambda: show("ActiveState")["ActiveState"] == "active", 90)
            report["silent_board"].update(show("NRestarts", "ActiveState", "MainPID"))
            report["silent_board"]["journal"] = run("journalctl", "-u", UNIT, "-o", "cat", "--no-pager")["stdout"]
        report["security"] = run("systemd-analyze", "security", "--no-pager", UNIT)
        report["final_stop"] = run("systemctl", "stop", UNIT)
    except Exception:  # noqa: BLE001 — the report says what broke; the host test fails on it
        report["driver_error"] = traceback.format_exc()
    finally:
        report["journal"] = run("journalctl", "-u", UNIT, "-o", "short-monotonic", "--no-pager")["stdout"]
        report_path.write_text(json.dumps(report, indent=1))
        Path(str(report_path) + ".done").touch()


def modbus_valid() -> bool:
    from drivers.published_values import StatusBits

    try:
        conn = ModbusConnection()
        try:
            return bool(conn.read_inputs(1, 1)[0] & StatusBits.VALID)
        finally:
            conn.sock.close()
    except OSError:
        return False


if __name__ == "__main__":
    main(Path(sys.argv[1]))
