"""Runs as a service under the real systemd of tests/inside_vm/systemd_job.sh and drives
the shipped unit the way an operator does: systemctl start, reload, stop; a Modbus
client on one TCP connection; journalctl -p err; a board that falls silent. Writes what
it saw as JSON (argv[1]); judges nothing itself: tests/daemon/test_systemd_vm.py does, on the host.
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


def run(*argv: str, timeout_s: float = 900, tail: int = 4000) -> dict:
    started = time.monotonic()
    r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
    return {"rc": r.returncode, "seconds": round(time.monotonic() - started, 3), "stdout": r.stdout[-tail:],
            "stderr": r.stderr[-tail:]}


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
        # generous: under emulation the plain-Python daemon may answer a read only after it
        # has worked through seconds of queued board bytes (each read drains the port first)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=120)
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


def watchdog_us() -> int:
    return int(show("WatchdogTimestampMonotonic")["WatchdogTimestampMonotonic"])


def main(report_path: Path) -> None:
    from drivers.published_values import StatusBits

    report: dict = {}
    try:
        report["start"] = run("systemctl", "start", UNIT)  # Type=notify: returns at READY=1
        # Result and ExecMainStatus (e.g. 238/STATE_DIRECTORY) say why a start failed, and the
        # unit's own journal what it printed: the test shows them when the start failed
        report["start"].update(show("ActiveState", "SubState", "StatusText", "WatchdogUSec", "MainPID",
                                    "TimeoutStartUSec", "TimeoutStopUSec", "Environment", "Result",
                                    "ExecMainCode", "ExecMainStatus"))
        if report["start"]["rc"] != 0:
            report["start"]["journal"] = run("journalctl", "-u", UNIT, "-o", "cat", "--no-pager")["stdout"]
        watchdog_s = seconds(show("WatchdogUSec")["WatchdogUSec"])
        # pings only once samples flow; then one per WatchdogSec/2
        first = wait_for(watchdog_us, 2 * watchdog_s) or 0
        time.sleep(1.2 * watchdog_s)  # a daemon that did not ping in here is restarted
        later = show("WatchdogTimestampMonotonic", "NRestarts", "ActiveState")
        report["watchdog_pings"] = {"watchdog_s": watchdog_s, "first_us": first,
                                    "later_us": int(later["WatchdogTimestampMonotonic"]),
                                    "restarts": int(later["NRestarts"]), "active": later["ActiveState"]}

        # Under emulation the plain-Python gateway and the emulated board share a slow CPU:
        # samples come with gaps, so the position is rarely VALID there (docs/daemon.md).
        # What is checked is systemd's part: one TCP connection, kept across reloads.
        modbus = ModbusConnection()
        map_version = modbus.read_inputs(0, 1)[0]
        report["reload"] = run("systemctl", "reload", UNIT)  # ExecReload: SIGHUP, returns at once
        # CONFIG_RELOADED is an event held EVENT_HOLD_S (10 s): it is watched from the reload
        # on, not read once after the journal said so — under emulation one journalctl call
        # can take longer than the hold. The watching is done on a connection of its own,
        # opened anew if it is dropped (counted in the report), so that the connection whose
        # survival is the test is used only before and after the reload.
        reload_sent = time.monotonic()
        read_seconds: list[float] = []
        watcher: list[ModbusConnection] = []
        dropped_watchers = 0

        def status_if_reloaded() -> int:
            nonlocal dropped_watchers
            asked = time.monotonic()
            try:
                if not watcher:
                    watcher.append(ModbusConnection())
                status = watcher[0].read_inputs(1, 1)[0]
            except OSError:  # ConnectionError, a timeout: a new watcher next time
                dropped_watchers += 1
                watcher.clear()
                return 0
            read_seconds.append(time.monotonic() - asked)
            return status & StatusBits.CONFIG_RELOADED

        after = wait_for(status_if_reloaded, 120, poll_s=0.1)
        bit_seen_s = time.monotonic() - reload_sent
        for w in watcher:
            w.sock.close()
        # the daemon's loop may take seconds to get to the signal here: wait for its word
        reloaded = wait_for(lambda: journal_count("config reloaded") >= 1, 120)
        report["reload"].update({"logged": bool(reloaded), "status_after": after or 0,
                                 "bit_seen_after_s": round(bit_seen_s, 2),
                                 "reads": len(read_seconds), "dropped_watchers": dropped_watchers,
                                 "slowest_read_s": round(max(read_seconds, default=0.0), 2),
                                 "logged_after_s": round(time.monotonic() - reload_sent, 2),
                                 "config_reloaded_bit": bool(after),
                                 "same_connection": modbus.read_inputs(0, 1)[0] == map_version,
                                 "restarts": int(show("NRestarts")["NRestarts"]),
                                 "main_pid": int(show("MainPID")["MainPID"])})

        good = CONFIG.read_text()
        CONFIG.write_text(good + "\n[modbus]\nbogus = 1\n")  # refused, logged as an error
        report["bad_reload"] = run("systemctl", "reload", UNIT)
        refused = wait_for(lambda: journal_count("reload refused") >= 1, 120)
        CONFIG.write_text(good)
        report["bad_reload"].update({"logged": bool(refused),
                                     "still_serving": modbus.read_inputs(0, 1)[0] == map_version,
                                     "restarts": int(show("NRestarts")["NRestarts"]),
                                     "main_pid": int(show("MainPID")["MainPID"]),
                                     "reloads_applied": journal_count("config reloaded")})
        report["journal_err"] = run("journalctl", "-p", "err", "-u", UNIT, "-o", "cat", "--no-pager")["stdout"]
        modbus.sock.close()

        # the board falls silent: SIGSTOP its process (the daemon's child with
        # port = "emulated"); no samples, so no WATCHDOG=1, so systemd restarts the unit.
        # Done before the stop so one cold start (minutes under emulation) is saved.
        main_pid = int(show("MainPID")["MainPID"])
        board = wait_for(lambda: board_pid(main_pid), 60)
        report["silent_board"] = {"main_pid": main_pid, "board_pid": board}
        if board:
            pinged = watchdog_us()
            report["silent_board"]["pinging_before"] = bool(wait_for(lambda: watchdog_us() > pinged, 2 * watchdog_s))
            os.kill(board, signal.SIGSTOP)
            stopped_at = time.monotonic()
            restarted = wait_for(lambda: int(show("NRestarts")["NRestarts"]) >= 1, 4 * watchdog_s)
            report["silent_board"].update({"restarted": bool(restarted),
                                           "seconds": round(time.monotonic() - stopped_at, 1)})
            back = wait_for(lambda: show("ActiveState", "SubState") == {"ActiveState": "active",
                                                                         "SubState": "running"}, 600)
            report["silent_board"]["back_after_s"] = round(time.monotonic() - stopped_at, 1) if back else None
            report["silent_board"].update(show("NRestarts", "ActiveState", "MainPID"))
            # samples flow again from the new board (and the stop below is from a running gateway)
            pinged = watchdog_us()
            report["silent_board"]["pinging_after"] = bool(wait_for(lambda: watchdog_us() > pinged, 2 * watchdog_s))

        report["stop"] = run("systemctl", "stop", UNIT)  # returns once the unit is inactive
        report["stop"].update(show("ActiveState", "Result"))
        state = Path("/var/lib/adxl-gateway/state.json")
        report["state"] = {"path": str(state), "resolved": str(state.resolve()), "exists": state.exists(),
                           "content": json.loads(state.read_text()) if state.exists() else None}
        report["security"] = run("systemd-analyze", "security", "--no-pager", UNIT)
    except Exception:  # noqa: BLE001 — the report says what broke; the host test fails on it
        report["driver_error"] = traceback.format_exc()
    finally:
        report["journal"] = run("journalctl", "-u", UNIT, "-o", "short-monotonic", "--no-pager",
                                tail=40000)["stdout"]
        report_path.write_text(json.dumps(report, indent=1))
        Path(str(report_path) + ".done").touch()


def journal_count(text: str) -> int:
    out = subprocess.run(["journalctl", "-u", UNIT, "-o", "cat", "--no-pager"], capture_output=True, text=True,
                         timeout=60).stdout
    return out.count(text)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
