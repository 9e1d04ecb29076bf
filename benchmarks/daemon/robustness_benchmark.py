"""Robustness benchmark: the attacks of issue 16 rerun against the real daemon, 127.0.0.1 only.

    .venv/bin/python -m benchmarks.daemon.robustness_benchmark [--flood 1100] [--fd-limit 1024] [--hold-s 6]
        [--reloads 20] [--only daemon|offline] [--json FILE]

The daemon (`adxlgw run`, emulated board, CAN off) runs as its own process with its
open-file limit lowered to --fd-limit (resource.setrlimit in the child before exec:
systemd's default is 1 024). A well-behaved PLC client at 127.0.0.2 — listed in
[modbus] write_allow, so a priority client — connects after each attack is in place
and polls 10 input registers every 20 ms on one connection, reconnecting on failure.
Per case the script prints: served (every PLC poll answered, and the case's own check),
the PLC's p99 round trip, the daemon's resident memory at the end and its peak, and the
bytes the daemon logged during the case (stderr).

Cases (each bounded in count and time):
- baseline: nothing but the PLC.
- idle flood: --flood idle connections from 127.0.0.1 (more than the fd limit), held.
- slowloris: 200 connections trickling one byte a second into a never-complete frame;
  check: all closed by the idle timeout (5 s here).
- malformed then valid: on one connection each, a bad MBAP header (protocol id 5,
  length 0, 1, 255, 0xFFFF) followed by valid requests; check: the connection is closed
  at once (before: open and deaf). And an undecodable request followed by 20 valid
  ones; check: all 21 answered.
- pipelining: 500 requests in one write; check: 500 answers, in order.
- bad-frame flood: 2 000 bad frames on new connections; check: log bytes bounded.
- fd exhaustion: max_connections raised above the fd limit (so the limit does not
  protect), the flood again; check: the log stays bounded (accept errors once per
  interval, no traceback per attempt). The PLC, connected before the flood, is served;
  new connections wait for asyncio's 1 s accept retry.
- hostile state files: the daemon started on each file of issue 16; check: it reaches
  "ready", the file is moved aside, POSITION is not NaN-from-the-file and
  NOT_REFERENCED is set.
- reload races: while the PLC polls on one connection, --reloads SIGHUPs 0.1 s apart,
  the config file replaced (atomically) before each: alternately a good change outside
  [modbus] (calibration.zero_g_duty_x) and a bad file (in turn: TOML nested 5 000 deep,
  and modbus.port set to a port this script holds); then 5 SIGHUPs back to back (reloads
  running at once) on a good file and, after a pause, 5 on the nested one; then the good
  file once more and a last SIGHUP. Check: the daemon lives, the PLC's
  connection is never dropped, every spaced SIGHUP ends in exactly one "config
  reloaded" (INFO) or "reload refused" (ERROR) line, as many refusals as bad files; each
  burst runs at least one reload (the kernel merges a SIGHUP sent while one is pending),
  each with its file's outcome; no traceback; the last good reload applies.

Then the offline commands (no daemon): `estimate` (realtime and smoothed), `fit-drift`,
`diagnose` and `import` on each hostile recording of issue 16, `config --check` on each
hostile config (the files: testing/hostile_files.py, shared with the tests), each command
in its own process; per run: exit code, stderr lines, the command's own peak RSS, wall
time. Goal: exit 2 with one error line (a warning before it allowed), or exit 0 where the
file is usable; no traceback; < 500 MB.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks import harness
from drivers.modbus_map import BY_NAME, WordOrder, decode_register
from drivers.published_values import StatusBits
from testing import hostile_files as hostile

ROOT = Path(__file__).resolve().parents[2]

ADXLGW = Path(sys.executable).with_name("adxlgw")
PLC_IP = "127.0.0.2"
FLOOD_IP = "127.0.0.1"
POLL_PERIOD_S = 0.02
READ_10 = b"\x04\x00\x00\x00\x0a"  # FC04 from address 0, 10 registers (status, position…)
COUNTERS = ("MODBUS_CLIENTS", "MODBUS_REFUSED_CONNECTIONS", "MODBUS_CLOSED_CONNECTIONS", "MODBUS_REJECTED_FRAMES")


def mbap(transaction: int, pdu: bytes, protocol: int = 0, length: int | None = None) -> bytes:
    return struct.pack(">HHHB", transaction, protocol, len(pdu) + 1 if length is None else length, 1) + pdu


def recv_exactly(sock: socket.socket, count: int) -> bytes:
    data = b""
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionError("closed by the server")
        data += chunk
    return data


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --------------------------------------------------------------------------- #
# The daemon
# --------------------------------------------------------------------------- #
class Daemon:
    def __init__(self, workdir: Path, fd_limit: int, *, max_connections: int = 64, idle_timeout_s: float = 5.0,
                 state_bytes: bytes | None = None):
        self.port = free_port()
        self.workdir = workdir
        self.state = workdir / "state.json"
        if state_bytes is not None:
            self.state.write_bytes(state_bytes)
        self.config = config = workdir / "gateway.toml"
        self.config_text = (
            '[serial]\nport = "emulated"\n'
            f'[modbus]\nport = {self.port}\nwrite_allow = ["{PLC_IP}"]\nmax_connections = {max_connections}\n'
            f"idle_timeout_s = {idle_timeout_s}\npeer_log_interval_s = 10.0\n"
            "[can]\nenabled = false\n"
            f'[state]\npath = "{self.state}"\n'
        )
        config.write_text(self.config_text)
        self.log_path = workdir / "daemon.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - the daemon's output for its whole life; closed in stop()
        limit = (fd_limit, fd_limit)
        self.process = subprocess.Popen(
            [str(ADXLGW), "run", "--config", str(config)], cwd=ROOT, stdout=self._log, stderr=subprocess.STDOUT,
            env={**os.environ, "NOTIFY_SOCKET": ""},
            preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, limit),
        )
        deadline = time.monotonic() + 60
        while b"ready:" not in self.log_path.read_bytes():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"daemon did not start: {self.log_path.read_text()[-2000:]}")
            time.sleep(0.1)

    def replace_config(self, data: bytes) -> None:
        """The config file replaced at once (written beside it, renamed over it)."""
        tmp = self.config.with_suffix(".tmp")
        tmp.write_bytes(data)
        os.replace(tmp, self.config)

    def log_since(self, offset: int, end: int | None = None) -> str:
        """The log from byte `offset` (to byte `end`)."""
        with open(self.log_path, "rb") as fh:
            fh.seek(offset)
            return fh.read(-1 if end is None else end - offset).decode("utf-8", "replace")

    def log_bytes(self) -> int:
        return self.log_path.stat().st_size

    def memory_mb(self) -> tuple[float, float]:
        """(resident now, peak resident), MB."""
        fields = {}
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            key, _, value = line.partition(":")
            fields[key] = value.strip()
        return int(fields["VmRSS"].split()[0]) / 1024, int(fields["VmHWM"].split()[0]) / 1024

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> int:
        self.process.send_signal(signal.SIGTERM)
        try:
            code = self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait(5)
        self._log.close()
        return code


# --------------------------------------------------------------------------- #
# The well-behaved PLC
# --------------------------------------------------------------------------- #
class Plc:
    def __init__(self, port: int):
        self.port = port
        self.sock: socket.socket | None = None
        self.transaction = 0
        self.errors: list[str] = []

    def _connect(self) -> None:
        self.sock = socket.create_connection(("127.0.0.1", self.port), timeout=2, source_address=(PLC_IP, 0))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def read(self) -> bytes:
        """One FC04 read of 10 registers; the answer's data bytes."""
        if self.sock is None:
            self._connect()
        self.transaction = (self.transaction + 1) & 0xFFFF
        self.sock.sendall(mbap(self.transaction, READ_10))
        answer = recv_exactly(self.sock, 9 + 20)
        if answer[:2] != struct.pack(">H", self.transaction) or answer[7] != 4:
            raise ConnectionError(f"unexpected answer {answer.hex()}")
        return answer[9:]

    def counters(self) -> dict[str, int]:
        """The server's own counters, read over Modbus like any client would."""
        first = BY_NAME["MODBUS_REQUESTS"].address
        last = BY_NAME["MODBUS_CLOSED_CONNECTIONS"]
        count = last.address + last.words - first
        if self.sock is None:
            self._connect()
        self.transaction = (self.transaction + 1) & 0xFFFF
        self.sock.sendall(mbap(self.transaction, struct.pack(">BHH", 4, first, count)))
        answer = recv_exactly(self.sock, 9 + 2 * count)
        words = list(struct.unpack(f">{count}H", answer[9:]))
        return {name: decode_register(BY_NAME[name], words[BY_NAME[name].address - first:], WordOrder.ABCD)
                for name in COUNTERS}

    def poll(self, count: int) -> tuple[list[float], int, bytes]:
        """`count` polls every POLL_PERIOD_S: round trips (s), failures, last data."""
        latencies, failures, last = [], 0, b""
        for _ in range(count):
            started = time.monotonic()
            try:
                last = self.read()
                latencies.append(time.monotonic() - started)
            except OSError as err:
                failures += 1
                self.errors.append(f"{type(err).__name__}: {err}")
                self.close()
            time.sleep(max(0.0, POLL_PERIOD_S - (time.monotonic() - started)))
        return latencies, failures, last

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


def p99_ms(latencies: list[float]) -> float:
    if not latencies:
        return math.nan
    ordered = sorted(latencies)
    return 1000 * ordered[min(len(ordered) - 1, math.ceil(0.99 * len(ordered)) - 1)]


def open_flood(port: int, count: int) -> tuple[list[socket.socket], int]:
    socks, failed = [], 0
    for _ in range(count):
        try:
            socks.append(socket.create_connection(("127.0.0.1", port), timeout=2, source_address=(FLOOD_IP, 0)))
        except OSError:
            failed += 1
    return socks, failed


def closed_at_once(sock: socket.socket, within_s: float = 1.0) -> bool:
    sock.settimeout(within_s)
    try:
        while True:
            if not sock.recv(4096):
                return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except TimeoutError:
        return False


# --------------------------------------------------------------------------- #
# Cases
# --------------------------------------------------------------------------- #
def run_case(name: str, daemon: Daemon, polls: int, attack=None, check=None, plc_first: bool = False) -> dict:
    """Set up `attack` (returns what to release), poll as the PLC, run `check`."""
    log_before = daemon.log_bytes()
    started = time.monotonic()
    plc = Plc(daemon.port)
    before = plc.counters()
    if not plc_first:
        plc.close()  # connect again once the attack is in place
    held = attack() if attack else None
    latencies, failures, _ = plc.poll(polls)
    ok_check, detail = check(held) if check else (True, "")
    try:
        try:
            after = plc.counters()
        except OSError:  # a check may have outlasted the idle timeout: a fresh connection
            plc.close()
            after = plc.counters()
        counts = (f"clients {after['MODBUS_CLIENTS']}, "
                  f"refused +{after['MODBUS_REFUSED_CONNECTIONS'] - before['MODBUS_REFUSED_CONNECTIONS']}, "
                  f"closed +{after['MODBUS_CLOSED_CONNECTIONS'] - before['MODBUS_CLOSED_CONNECTIONS']}, "
                  f"rejected frames +{after['MODBUS_REJECTED_FRAMES'] - before['MODBUS_REJECTED_FRAMES']}")
    except OSError as err:
        ok_check, counts = False, f"counters not readable: {err}"
    detail = f"{detail}; {counts}" if detail else counts
    if plc.errors:
        detail += f"; PLC errors: {sorted(set(plc.errors))[:3]}"
    if isinstance(held, dict):
        for sock in held.get("sockets", []):
            sock.close()
        if held.get("stop"):
            held["stop"].set()
    plc.close()
    elapsed = time.monotonic() - started
    rss, peak = daemon.memory_mb()
    log_bytes = daemon.log_bytes() - log_before
    return {
        "case": name, "served": failures == 0 and ok_check and daemon.alive(), "plc_polls": polls,
        "plc_failures": failures, "p99_ms": round(p99_ms(latencies), 2), "rss_mb": round(rss, 1),
        "peak_rss_mb": round(peak, 1), "log_bytes": log_bytes, "log_bytes_per_s": round(log_bytes / elapsed),
        "detail": detail,
    }


def idle_flood(daemon: Daemon, count: int):
    def attack():
        socks, failed = open_flood(daemon.port, count)
        return {"sockets": socks, "connect_failures": failed}

    def check(held):
        return True, f"{len(held['sockets'])} opened, {held['connect_failures']} connects failed"

    return attack, check


def slowloris(daemon: Daemon, count: int = 200):
    def attack():
        socks, _ = open_flood(daemon.port, count)
        stop = threading.Event()
        for sock in socks:
            sock.sendall(struct.pack(">HHHB", 1, 0, 254, 1))  # announces 253 bytes that never all come

        def trickle():
            while not stop.wait(1.0):
                for sock in socks:
                    with contextlib.suppress(OSError):
                        sock.send(b"\x00")

        threading.Thread(target=trickle, daemon=True).start()
        return {"sockets": socks, "stop": stop, "t0": time.monotonic()}

    def check(held):
        remaining = max(0.0, held["t0"] + 5.0 + 2.0 - time.monotonic())  # idle timeout 5 s, sweep margin
        time.sleep(remaining)
        closed = sum(closed_at_once(sock, 0.05) for sock in held["sockets"])
        return (closed == len(held["sockets"]),
                f"{closed} of {len(held['sockets'])} closed (refused at once or by the idle timeout)")

    return attack, check


def malformed_then_valid(daemon: Daemon):
    headers = {"protocol id 5": (5, None), "length 0": (0, 0), "length 1": (0, 1), "length 255": (0, 255),
               "length 0xFFFF": (0, 0xFFFF)}

    def check(_):
        results = []
        for protocol, length in headers.values():
            with socket.create_connection(("127.0.0.1", daemon.port), timeout=2) as sock:
                sock.sendall(mbap(1, READ_10, protocol=protocol, length=length) + b"".join(
                    mbap(t, READ_10) for t in range(2, 20)))
                results.append(closed_at_once(sock))
        with socket.create_connection(("127.0.0.1", daemon.port), timeout=2) as sock:
            sock.sendall(mbap(1, b"\x04\x00") + b"".join(mbap(t, READ_10) for t in range(2, 22)))
            try:
                first = recv_exactly(sock, 9)
                rest = [recv_exactly(sock, 29) for _ in range(20)]
                undecodable_ok = first[7:9] == b"\x84\x03" and all(
                    r[:2] == struct.pack(">H", t) for t, r in zip(range(2, 22), rest, strict=False))
            except OSError:
                undecodable_ok = False
        closed = sum(results)
        return closed == len(results) and undecodable_ok, (
            f"bad header: {closed}/{len(results)} connections closed at once; undecodable + 20 valid: "
            f"{'all answered' if undecodable_ok else 'NOT all answered'}")

    return None, check


def pipelining(daemon: Daemon, count: int = 500):
    def check(_):
        with socket.create_connection(("127.0.0.1", daemon.port), timeout=5) as sock:
            sock.sendall(b"".join(mbap(t, READ_10) for t in range(count)))
            try:
                answers = [recv_exactly(sock, 29) for _ in range(count)]
            except OSError as err:
                return False, f"{err}"
        in_order = all(a[:2] == struct.pack(">H", t) for t, a in enumerate(answers))
        return in_order, f"{len(answers)} of {count} answered{', in order' if in_order else ', OUT OF ORDER'}"

    return None, check


def bad_frame_flood(daemon: Daemon, count: int = 2000):
    def check(_):
        for t in range(count):
            with socket.create_connection(("127.0.0.1", daemon.port), timeout=2) as sock:
                sock.sendall(mbap(t, READ_10, protocol=7))
                closed_at_once(sock)
        return True, f"{count} bad frames sent"

    return None, check


def reload_races(daemon: Daemon, count: int, gap_s: float = 0.1):
    """SIGHUPs in quick succession, good and bad config files in turn (see the module doc)."""
    held_port = socket.socket()
    held_port.bind(("127.0.0.1", 0))
    held_port.listen()
    busy = held_port.getsockname()[1]
    good = [daemon.config_text.replace('[serial]\n', f'[calibration]\nzero_g_duty_x = {duty}\n[serial]\n')
            for duty in (0.5005, 0.4995)]
    nested = daemon.workdir / "nested.toml"
    bad = {"TOML nested 5 000 deep": hostile.nested_toml(nested).read_bytes(),
           "modbus.port in use": daemon.config_text.replace(f"port = {daemon.port}\n", f"port = {busy}\n").encode()}
    plan = []  # (kind, bytes)
    for k in range(count):
        if k % 2 == 0:
            plan.append(("good", good[(k // 2) % 2].encode()))
        else:
            name = list(bad)[(k // 2) % len(bad)]
            plan.append((name, bad[name]))

    # then bursts: `burst` SIGHUPs back to back (reloads running at once) on a good file,
    # a pause, the same on a bad one. The kernel merges a SIGHUP sent while another is still
    # pending, so a burst runs 1 to `burst` reloads: each must match its file
    burst = 5
    bursts = [("good", good[1].encode()), ("bad", bad["TOML nested 5 000 deep"])]

    def outcomes(text: str) -> tuple[int, int]:
        lines = text.splitlines()
        return (sum("config reloaded from" in line for line in lines),
                sum("reload refused" in line or "reload failed" in line for line in lines))

    def settle(since: int, at_least: int) -> int:
        """Wait until `at_least` reloads ended since `since`, and 0.5 s more without one."""
        deadline = time.monotonic() + 20
        while sum(outcomes(daemon.log_since(since))) < at_least and time.monotonic() < deadline:
            time.sleep(0.1)
        seen = -1
        while seen != sum(outcomes(daemon.log_since(since))) and time.monotonic() < deadline:
            seen = sum(outcomes(daemon.log_since(since)))
            time.sleep(0.5)
        return daemon.log_bytes()

    def attack():
        marks = [daemon.log_bytes()]

        def storm():
            for _, data in plan:
                daemon.replace_config(data)
                daemon.process.send_signal(signal.SIGHUP)
                time.sleep(gap_s)
            marks.append(settle(marks[-1], count))
            for _, data in bursts:
                daemon.replace_config(data)
                for _ in range(burst):
                    daemon.process.send_signal(signal.SIGHUP)
                marks.append(settle(marks[-1], 1))

        thread = threading.Thread(target=storm, daemon=True)
        thread.start()
        return {"thread": thread, "marks": marks, "sockets": [held_port]}

    def check(held):
        held["thread"].join()
        marks = held["marks"]
        spaced = daemon.log_since(marks[0], marks[1])
        applied, refused = outcomes(spaced)
        n_bad = sum(kind != "good" for kind, _ in plan)
        in_bursts = []
        for k, (kind, _) in enumerate(bursts):
            a, r = outcomes(daemon.log_since(marks[k + 1], marks[k + 2]))
            in_bursts.append((kind, a, r))
        bursts_ok = all((a + r >= 1) and (r == 0 if kind == "good" else a == 0) for kind, a, r in in_bursts)
        text = daemon.log_since(marks[0])
        refusals = [line for line in text.splitlines() if "reload refused" in line or "reload failed" in line]
        at_error = all(line.startswith(("ERROR", "<3>")) for line in refusals)
        reasons = {name: sum(1 for line in refusals if key in line)
                   for name, key in (("nested", "nested too deeply"), ("port in use", "in use"))}
        # the last word: the good file again, one more SIGHUP, applied
        before = daemon.log_bytes()
        daemon.replace_config(good[0].encode())
        daemon.process.send_signal(signal.SIGHUP)
        settle(before, 1)
        final_applied = outcomes(daemon.log_since(before)) == (1, 0)
        traceback = "Traceback" in daemon.log_since(marks[0])
        ok = (daemon.alive() and applied + refused == count and refused == n_bad and bursts_ok and at_error
              and final_applied and not traceback)
        burst_text = ", ".join(f"{kind} file: {a} applied, {r} refused" for kind, a, r in in_bursts)
        return ok, (f"{count} SIGHUPs {gap_s:g} s apart: {applied} applied, {refused} refused of {n_bad} bad; "
                    f"bursts of {burst} back to back: {burst_text}; refusals ({reasons['nested']} nested, "
                    f"{reasons['port in use']} port in use) at ERROR: {'all' if at_error else 'NOT all'}; last good "
                    f"reload applied: {'yes' if final_applied else 'NO'}; traceback: {'YES' if traceback else 'none'}; "
                    f"daemon alive: {'yes' if daemon.alive() else 'NO'}")

    return attack, check


# --------------------------------------------------------------------------- #
# The offline commands on hostile files
# --------------------------------------------------------------------------- #
RECORDING_COMMANDS = {
    "estimate realtime": lambda f, d: ["estimate", f, "--out", d / "out.csv"],
    "estimate smoothed": lambda f, d: ["estimate", f, "--method", "smoothed", "--out", d / "out.parquet"],
    "fit-drift": lambda f, d: ["fit-drift", f, "--plot", d / "drift.png"],
    "diagnose": lambda f, d: ["diagnose", f],
}
GOAL_RSS_MB = 500


def hostile_recordings(workdir: Path) -> dict[str, tuple[Path, list[str]]]:
    """name → (file, import's column options for the same file without its metadata)."""
    sim = hostile.simulated_run()
    raw_cols = ["--time-col", "seq", "--acc-col", "t1x"]  # a time counting down, repeating: seq
    acc_cols = ["--time-col", "t_s", "--acc-col", "acc_x_mps2"]
    return {
        "seq counting down": (hostile.seq_counting_down(workdir / "down.csv", sim), raw_cols),
        "same seq on every row": (hostile.seq_repeating(workdir / "same.csv", sim), raw_cols),
        f"a field of {hostile.LONG_FIELD_CHARS} characters": (hostile.long_field(workdir / "long.csv"), acc_cols),
        "a non-UTF-8 byte near the end": (hostile.non_utf8_in_the_data(workdir / "latin.csv", sim), raw_cols),
        "noise-free rest": (hostile.quiet_rest(workdir / "still.csv", step_mg=None), acc_cols),
        "10 mg-quantised rest": (hostile.quiet_rest(workdir / "quant.csv", step_mg=10.0), acc_cols),
        "one 1e300 sample in noise": (hostile.impossible_samples(workdir / "huge.csv"), acc_cols),
        "truncated last line": (hostile.truncated(workdir / "cut.csv", sim), raw_cols),
    }


def run_offline(args: list, cwd: Path) -> dict:
    """One command in its own process (started from a bare launcher, so its peak RSS is its
    own: testing/hostile_files.run_measured): exit code, stderr lines, peak RSS, wall time."""
    code, stderr, peak, wall = hostile.run_measured([ADXLGW, *args], cwd=cwd)
    lines = stderr.strip().splitlines()
    return {"exit": code, "stderr_lines": len(lines), "error_lines": sum(": error: " in line for line in lines),
            "peak_rss_mb": round(peak / 2**20, 1), "wall_s": round(wall, 2), "traceback": "Traceback" in stderr,
            "last_line": lines[-1][:160] if lines else ""}


def offline_cases(workdir: Path) -> list[dict]:
    files = workdir / "files"
    files.mkdir()
    out = workdir / "out"
    out.mkdir()
    runs = []
    for name, (path, import_cols) in hostile_recordings(files).items():
        commands = {c: make(path, out) for c, make in RECORDING_COMMANDS.items()}
        foreign = hostile.without_metadata(path, files / f"foreign-{path.name}")
        commands["import"] = ["import", foreign, *import_cols, "--out", out / "imported.csv"]
        for command, args in commands.items():
            runs.append(offline_run(name, command, args, out))
    configs = {"TOML nested 5 000 deep (arrays)": hostile.nested_toml(files / "arrays.toml"),
               "TOML nested 5 000 deep (inline tables)": hostile.nested_toml(files / "tables.toml", inline_tables=True)}
    for name, path in configs.items():
        runs.append(offline_run(name, "config --check", ["config", "--check", path], out))
    return runs


def offline_run(name: str, command: str, args: list, cwd: Path) -> dict:
    r = {"case": f"{name}: {command}", "file": name, "command": command, **run_offline(args, cwd)}
    # "served" for the table: the goal met — a refusal in one error line (warnings said before
    # it are allowed), or the file used without an error — no traceback, within memory
    one_line_refusal = r["exit"] == 2 and r["error_lines"] == 1
    used = r["exit"] == 0 and r["error_lines"] == 0
    r["served"] = (one_line_refusal or used) and not r["traceback"] and r["peak_rss_mb"] < GOAL_RSS_MB
    print(format_offline(r), flush=True)
    return r


def format_offline(r: dict) -> str:
    return (f"{r['file']:<42} {r['command']:<18} goal: {'yes' if r['served'] else 'NO '}  exit {r['exit']:3d}  "
            f"stderr lines {r['stderr_lines']:3d} "
            f"(errors {r['error_lines']})  "
            f"peak RSS {r['peak_rss_mb']:6.1f} MB  {r['wall_s']:6.2f} s  {'TRACEBACK  ' if r['traceback'] else ''}"
            f"{r['last_line']}")


STATE_FILES = {
    "string position": b'{"version": 1, "last_position_m": "abc"}',
    "NaN position": b'{"version": 1, "last_position_m": NaN}',
    "Infinity tare": b'{"version": 1, "tare_offset_m": Infinity}',
    "1e308 position": b'{"version": 1, "last_position_m": 1e308}',
    "nested 5000 deep": b"[" * 5000 + b"]" * 5000,
    "non-UTF-8": b'{"version": 1, "tare_offset_m": 0.1} \xff',
}


def hostile_state(workdir: Path, name: str, data: bytes, fd_limit: int) -> dict:
    case_dir = workdir / f"state-{len(list(workdir.iterdir()))}"
    case_dir.mkdir()
    started = time.monotonic()
    try:
        daemon = Daemon(case_dir, fd_limit, state_bytes=data)
    except RuntimeError as err:
        return {"case": f"state file: {name}", "served": False, "detail": str(err)[-300:]}
    plc = Plc(daemon.port)
    latencies, failures, answer = plc.poll(25)
    plc.close()
    status = StatusBits(struct.unpack(">H", answer[2:4])[0]) if answer else StatusBits(0)
    moved = list(case_dir.glob("state.json.bad-*"))
    rss, peak = daemon.memory_mb()
    log_bytes = daemon.log_bytes()
    code = daemon.stop()
    ok = failures == 0 and bool(moved) and StatusBits.NOT_REFERENCED in status and code == 0
    return {
        "case": f"state file: {name}", "served": ok, "plc_polls": 25, "plc_failures": failures,
        "p99_ms": round(p99_ms(latencies), 2), "rss_mb": round(rss, 1), "peak_rss_mb": round(peak, 1),
        "log_bytes": log_bytes, "log_bytes_per_s": round(log_bytes / (time.monotonic() - started)),
        "detail": f"moved aside: {bool(moved)}; NOT_REFERENCED: {StatusBits.NOT_REFERENCED in status}; exit {code}",
    }


def daemon_cases(workdir: Path, args, polls: int) -> list[dict]:
    rows = []
    main_dir = workdir / "main"
    main_dir.mkdir()
    daemon = Daemon(main_dir, args.fd_limit)
    try:
        cases = [
            ("baseline", (None, None), False),
            (f"idle flood {args.flood}", idle_flood(daemon, args.flood), False),
            ("slowloris 200", slowloris(daemon), False),
            ("malformed then valid", malformed_then_valid(daemon), False),
            ("pipelining 500", pipelining(daemon), False),
            ("bad-frame flood 2000", bad_frame_flood(daemon), False),
            (f"reload races: {args.reloads} SIGHUPs", reload_races(daemon, args.reloads), True),
        ]
        for name, (attack, check), plc_first in cases:
            # the reload race polls twice as long: its storm and bursts take ~6 s
            rows.append(run_case(name, daemon, polls * (2 if name.startswith("reload") else 1), attack, check,
                                 plc_first))
            print(format_row(rows[-1]), flush=True)
    finally:
        daemon.stop()
    fd_dir = workdir / "fd"
    fd_dir.mkdir()
    # no limit, no idle timeout: only the accept-error handling stands between the flood and the log
    exhausted = Daemon(fd_dir, args.fd_limit, max_connections=10_000, idle_timeout_s=0)
    try:
        rows.append(run_case(f"fd exhaustion {args.flood} (max_connections above the fd limit)", exhausted,
                             polls, *idle_flood(exhausted, args.flood), plc_first=True))
        print(format_row(rows[-1]), flush=True)
    finally:
        exhausted.stop()
    for name, data in STATE_FILES.items():
        rows.append(hostile_state(workdir, name, data, args.fd_limit))
        print(format_row(rows[-1]), flush=True)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flood", type=int, default=1100, help="idle connections in the flood cases")
    parser.add_argument("--fd-limit", type=int, default=1024, help="the daemon's open-file limit")
    parser.add_argument("--hold-s", type=float, default=6.0, help="how long the PLC polls during each attack")
    parser.add_argument("--reloads", type=int, default=20, help="SIGHUPs in the reload-race case")
    parser.add_argument("--only", choices=("daemon", "offline"), help="run only the daemon or the offline cases")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args()
    polls = max(10, round(args.hold_s / POLL_PERIOD_S))
    harness.stamp("benchmarks.daemon.robustness_benchmark")
    print(f"# load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"# daemon open-file limit {args.fd_limit}; flood {args.flood}; PLC polls every "
          f"{POLL_PERIOD_S * 1000:.0f} ms for {args.hold_s:g} s per case")
    rows = []
    with tempfile.TemporaryDirectory(prefix="adxlgw-robust-") as tmp:
        workdir = Path(tmp)
        if args.only != "offline":
            rows += daemon_cases(workdir, args, polls)
        if args.only != "daemon":
            print("# offline commands on hostile files, each in its own process "
                  "(its own peak RSS: started from a bare launcher)")
            rows += offline_cases(workdir)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0 if all(r["served"] for r in rows) else 1


def format_row(r: dict) -> str:
    if "p99_ms" not in r:
        return f"{r['case']:<58} served: {'yes' if r['served'] else 'NO'}  {r['detail']}"
    return (f"{r['case']:<58} served: {'yes' if r['served'] else 'NO ':<3}  p99 {r['p99_ms']:7.2f} ms  "
            f"failures {r['plc_failures']:3d}/{r['plc_polls']}  "
            f"RSS {r['rss_mb']:6.1f} MB (peak {r['peak_rss_mb']:6.1f})"
            f"  log {r['log_bytes']:7d} B ({r['log_bytes_per_s']} B/s)  {r['detail']}")


if __name__ == "__main__":
    sys.exit(main())
