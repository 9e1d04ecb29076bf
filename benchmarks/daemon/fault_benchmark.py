"""Faults played into the real daemon on a pty, scored against the truth (issues 13 and 31).

    .venv/bin/python -m benchmarks.daemon.fault_benchmark [--cases NAME,...] [--seed 0]
    .venv/bin/python -m benchmarks.daemon.fault_benchmark --trace "outage 2 s"   # every read of one case

Each case is one board script: the paper's strokes (30 cm, 1 m/s, 1 s dwells, 2 s rest
first) simulated with the project's simulator (the truth), encoded as the board's
frames and written by daemon_benchmark's writer at 500 frames/s in real time into a pty
that `adxlgw run` (a child process, CAN off, estimator.start_at_rest = true, travel_m = TRAVEL_M) reads. The
fault hits the third stroke at a phase: acceleration, cruise, deceleration or rest (mid
dwell). Cases: no fault (the control); gaps of 5/10/20/50 ms (slots with no bytes, seq
keeps its gap) at each phase; kill -9 of the daemon mid-cruise and a start again on the
same state file (with start_at_rest false on the restart — what a restart can honestly
promise — and with the same config); a board reset mid-cruise (a HELLO, seq from 0); a
5 mg offset step mid-cruise; 2 s and 8 s outages from mid-cruise (nothing on the line).
The restarts, the board reset and the outages each with the first true stop after the
fault lasting 1, 5 or 20 s (the paper's dwell, a PLC's pause, and longer than any
cruise can last within the machine's travel, `estimator.travel_m` = TRAVEL_M: a stop is
then accepted on quiet alone). Two more: an orderly
stop (SIGTERM) at rest at +0.3 m, the axis moved back to 0 while the gateway is down,
a start again with start_at_rest = true; and a hostile but plausible state file (9999 m
with the orderly-stop mark) before the first start.
The restarts use a longer, robot-like move (0.8 m at 0.25 m/s, 3.1 s of cruise) and kill
1 s into its cruise: the daemon takes 0.3–2 s to answer again on this machine, and on the
paper's 0.2 s cruise it would come back with the axis already at rest.

A poller reads all input registers over Modbus TCP every 20 ms and time-stamps each
answer; a read is aligned to the sample the daemon had processed by its SAMPLE_COUNTER
(per daemon lifetime, the counter's offset to the samples written is the smallest
"written by then − counter" over the reads: the backlog is zero at some read). Reads
before the first sample (no position yet) and after the script's last frame (the board
gone quiet) are not scored.

Per case: the error at each of the next real stops after the fault (the last read in
the stop; V = VALID set there), how long after the fault VALID was first seen clear and
POSITION_UNTRUSTED first seen set, whether VALID stayed clear until a read inside a true
stop (then VALID again: the error there), reads with VALID set and |error| > 5 mm
after the fault, reads VALID with |error| > 3·POSITION_STD (over the whole run: never
confidently wrong), and the share of reads with |error| ≤ 3·POSITION_STD. The goal (issue
31): no read VALID beyond 3σ in any case ("goal met"); issue 13's (error ≤ 5 mm at the
next real stop, or flagged within 2 s and kept until a stop) is in the columns before it.
The first daemon start after an edit of gateway/ or drivers/ compiles the kernels anew:
run the benchmark from a checkout that is not being edited.
"""
from __future__ import annotations

import argparse
import datetime
import json
import multiprocessing as mp
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.daemon.daemon_benchmark import free_port, writer
from benchmarks.harness import machine
from benchmarks.modbus_poll import InputPoller
from drivers.pty_port import PtyPort
from drivers.published_values import StatusBits
from testing.fault_cases import (
    HOSTILE_POSITION_M,
    SLOT_S,
    STOPS_SCORED,
    TRAVEL_M,
    BoardScript,
    Case,
    all_cases,
    board_script,
)

ROOT = Path(__file__).resolve().parents[2]

FLAG_WITHIN_S = 2.0
ERROR_GOAL_M = 5e-3
POLL_S = 0.02
START_LIMIT_S = 300


# --------------------------------------------------------------------------- the daemon
def write_config(path: Path, link: Path, port: int, state: Path, start_at_rest: bool) -> None:
    path.write_text(
        f'[serial]\nport = "{link}"\n[modbus]\nport = {port}\n[can]\nenabled = false\n'
        f'[estimator]\nstart_at_rest = {"true" if start_at_rest else "false"}\ntravel_m = {list(TRAVEL_M)}\n'
        f'[state]\npath = "{state}"\n[service]\nlog_level = "warning"\n')


def start_daemon(config: Path, port: int, pty: PtyPort, log) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "run", "--config", str(config)],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=log)
    # generous: the first start after an edit compiles the kernels anew (gateway/compiled_cache.py),
    # minutes on a loaded 2-core machine; the scores do not depend on it
    deadline = time.monotonic() + START_LIMIT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the daemon exited with {proc.returncode}: see {log.name}")
        if pty.has_reader():
            return proc
        time.sleep(0.02)
    proc.kill()
    raise SystemExit(f"the daemon never opened the board port within {START_LIMIT_S} s")


def write_hostile_state(path: Path) -> None:
    """A state file within the file's own limits that says the axis stood, in order, far away."""
    now = time.time()
    path.write_text(json.dumps({"version": 1, "tare_offset_m": 0.0, "bias_estimate_mps2": 0.0,
                                "last_position_m": HOSTILE_POSITION_M, "saved_at_unix_s": now,
                                "stopped_at_rest_unix_s": now}))


# --------------------------------------------------------------------------- the poller
FIELDS = ("SAMPLE_COUNTER", "POSITION", "POSITION_STD", "STATUS", "STATUS_EXT")


def poller(port: int, until_ns: int, conn) -> None:
    """All input registers every POLL_S: (answer time ns, *FIELDS); reconnects while the daemon is away."""
    poller = InputPoller(port, FIELDS)
    reads = []
    next_ns = time.monotonic_ns()
    while time.monotonic_ns() < until_ns:
        next_ns += int(POLL_S * 1e9)
        read = poller.read()  # None: the daemon is being killed or restarted, try again next period
        if read is not None:
            reads.append((time.monotonic_ns(), *read))
        time.sleep(max(0.0, (next_ns - time.monotonic_ns()) / 1e9))
    poller.close()
    conn.send(reads)


# --------------------------------------------------------------------------- one case
def play(case: Case, script: BoardScript, tmp: Path) -> tuple[np.ndarray, list[tuple], int, int | None]:
    """Runs the case; returns the written times (ns, 0: not written), the reads, the start and the kill time."""
    pty = PtyPort(tmp / "board")
    port = free_port()
    config = tmp / "gw.toml"
    write_config(config, pty.link, port, tmp / "state.json", start_at_rest=True)
    if case.kind == "hostile":
        write_hostile_state(tmp / "state.json")
    # the log outlives each daemon start (a restart appends to it): closed after the last one
    with open(tmp / "daemon.log", "w") as log:
        daemon = start_daemon(config, port, pty, log)
        start_ns = time.monotonic_ns() + int(1.0e9)
        end_ns = start_ns + int(len(script.frames) * SLOT_S * 1e9) + int(0.3e9)
        ctx = mp.get_context("fork")
        w_recv, w_send = ctx.Pipe(False)
        p_recv, p_send = ctx.Pipe(False)
        wproc = ctx.Process(target=writer, args=(pty.master_fd, script.frames, start_ns, w_send, pty))
        pproc = ctx.Process(target=poller, args=(port, end_ns, p_send))
        wproc.start()
        pproc.start()
        kill_ns = None
        try:
            if script.kill_slot is not None:
                due = start_ns + int(script.kill_slot * SLOT_S * 1e9)
                time.sleep(max(0.0, (due - time.monotonic_ns()) / 1e9))
                if case.kind == "moved":  # an orderly stop: the last state is written, at rest
                    daemon.send_signal(signal.SIGTERM)
                else:
                    daemon.kill()  # SIGKILL: no shutdown, no last state write
                daemon.wait(timeout=10)
                kill_ns = time.monotonic_ns()
                if script.restart_slot is not None:
                    due = start_ns + int(script.restart_slot * SLOT_S * 1e9)
                    time.sleep(max(0.0, (due - time.monotonic_ns()) / 1e9))
                write_config(config, pty.link, port, tmp / "state.json", start_at_rest=case.restart_at_rest)
                daemon = start_daemon(config, port, pty, log)
            written = w_recv.recv()
            reads = p_recv.recv()
        finally:
            wproc.join(timeout=30)
            pproc.join(timeout=30)
            daemon.send_signal(signal.SIGTERM)
            try:
                daemon.wait(timeout=15)
            except subprocess.TimeoutExpired:
                daemon.kill()
                daemon.wait()
            pty.close(remove_link=True)
    return written, reads, start_ns, kill_ns


@dataclass
class Score:
    stop_errors_m: list[float] = field(default_factory=list)
    stop_valid: list[bool] = field(default_factory=list)
    clear_delay_s: float | None = None  # fault → first read with VALID clear
    flag_delay_s: float | None = None  # fault → first read with POSITION_UNTRUSTED set
    revalidated_in_stop: bool | None = None  # None: still flagged at the end of the run
    revalidated_error_m: float | None = None
    valid_wrong_reads: int = 0
    valid_beyond_3sigma: int = 0  # reads VALID with |error| > 3·POSITION_STD (or σ unknown): never
    covered: int = 0
    finite: int = 0
    reads: int = 0
    offsets: list[int] = field(default_factory=list)

    @property
    def flagged_ok(self) -> bool:
        return (self.flag_delay_s is not None and self.flag_delay_s <= FLAG_WITHIN_S
                and self.clear_delay_s is not None and self.clear_delay_s <= FLAG_WITHIN_S
                and self.revalidated_in_stop is not False)

    def meets_goal(self, case: Case) -> bool:
        """The goal (issue 31): no read VALID beyond 3·POSITION_STD, whatever the fault.
        (Issue 13's — error ≤ 5 mm at the next stop, or flagged within 2 s and kept until
        a true stop — is shown in the columns before: a restart cannot flag within 2 s
        while the daemon is down.)"""
        return self.valid_beyond_3sigma == 0


def align(written: np.ndarray, frames: list[bytes], reads: list[tuple], kill_ns: int | None):
    """Slot of the newest sample each read shows (-1: none yet), and the offsets found per lifetime."""
    delivered = np.flatnonzero((written > 0) & np.array([len(f) > 0 for f in frames]))
    delivered_ns = written[delivered]
    t = np.array([r[0] for r in reads], dtype=np.int64)
    counter = np.array([r[1] for r in reads], dtype=np.int64)
    life = np.zeros(len(reads), dtype=np.int64)
    if kill_ns is not None:
        life[t > kill_ns] = 1
    life += np.concatenate([[0], np.cumsum(np.diff(counter) < 0)])  # a counter that restarts
    slots = np.full(len(reads), -1, dtype=np.int64)
    offsets = []
    for seg in np.unique(life):
        idx = np.flatnonzero((life == seg) & (counter > 0))
        if not idx.size:
            continue
        before = np.searchsorted(delivered_ns, t[idx], side="right")
        offset = int(np.min(before - counter[idx]))
        offsets.append(offset)
        k = np.clip(offset + counter[idx] - 1, 0, len(delivered) - 1)
        slots[idx] = delivered[k]
    return slots, offsets


def score(case: Case, script: BoardScript, written: np.ndarray, reads: list[tuple], start_ns: int,
          kill_ns: int | None) -> Score:
    # reads after the script's last frame see a board gone quiet (STALE): not a fault of the case
    reads = [r for r in reads if r[0] <= written.max()]
    s = Score(reads=len(reads))
    if not reads:
        return s
    slots, s.offsets = align(written, script.frames, reads, kill_ns)
    t = np.array([r[0] for r in reads], dtype=np.int64)
    pos = np.array([r[2] for r in reads], dtype=float)
    std = np.array([r[3] for r in reads], dtype=float)
    status = np.array([r[4] for r in reads], dtype=np.int64)
    seen = slots >= 0
    err = np.where(seen, pos - script.ref_pos_m[np.maximum(slots, 0)], np.nan)
    finite = seen & np.isfinite(err) & np.isfinite(std)
    s.finite = int(finite.sum())
    s.covered = int((np.abs(err[finite]) <= 3 * std[finite]).sum())
    valid = (status & StatusBits.VALID) != 0
    untrusted = (status & StatusBits.POSITION_UNTRUSTED) != 0
    # VALID is a promise about the reported σ too: a read VALID outside ±3σ of the truth is
    # confidently wrong, whatever the size of the error (a NaN σ promises nothing: counted)
    beyond = ~(np.abs(err) <= 3 * std)
    s.valid_beyond_3sigma = int((seen & valid & beyond).sum())
    if case.kind == "none":
        return s
    fault_ns = start_ns + int(script.fault_slot * SLOT_S * 1e9)
    after = seen & (slots >= script.fault_slot)
    s.valid_wrong_reads = int((after & valid & (np.abs(np.nan_to_num(err, nan=np.inf)) > ERROR_GOAL_M)).sum())
    in_stop = np.zeros(len(reads), dtype=bool)
    for first, last in script.stops:
        in_stop |= seen & (slots >= first) & (slots <= last)
        if first <= script.fault_slot or len(s.stop_errors_m) >= STOPS_SCORED:
            continue
        here = np.flatnonzero(seen & (slots >= first) & (slots <= last))
        if here.size:
            s.stop_errors_m.append(float(err[here[-1]]))
            s.stop_valid.append(bool(valid[here[-1]]))
    flagged = np.flatnonzero((t >= fault_ns) & untrusted)
    if flagged.size:
        s.flag_delay_s = (t[flagged[0]] - fault_ns) / 1e9
    cleared = np.flatnonzero((t >= fault_ns) & ~valid)
    if cleared.size:
        s.clear_delay_s = (t[cleared[0]] - fault_ns) / 1e9
        # kept: VALID comes back (if at all) only on a read inside a true stop
        back = np.flatnonzero((np.arange(len(reads)) > cleared[0]) & valid)
        if back.size:
            s.revalidated_in_stop = bool(in_stop[back[0]])
            s.revalidated_error_m = float(err[back[0]])
    return s


def mm(x: float | None) -> str:
    return "–" if x is None or not np.isfinite(x) else f"{x * 1e3:+.1f}"


def row(case: Case, s: Score) -> str:
    stops = ", ".join(f"{mm(e)}{' V' if v else ''}" for e, v in zip(s.stop_errors_m, s.stop_valid, strict=False)) or "–"
    flag = "–" if s.clear_delay_s is None else (
        f"{s.clear_delay_s:.2f} s / " + ("never" if s.flag_delay_s is None else f"{s.flag_delay_s:.2f} s"))
    kept = {None: "to the end", True: f"yes ({mm(s.revalidated_error_m)} mm)",
            False: f"**no** ({mm(s.revalidated_error_m)} mm)"}[s.revalidated_in_stop] \
        if s.clear_delay_s is not None else "–"
    cover = f"{100 * s.covered / s.finite:.1f} % of {s.finite}" if s.finite else "–"
    goal = "yes" if s.meets_goal(case) else "**no**"
    return (f"| {case.name} | {stops} | {flag} | {kept} | {s.valid_wrong_reads} | {s.valid_beyond_3sigma} | {cover} "
            f"| {goal} |")


def print_trace(case: Case, script: BoardScript, written, reads, start_ns: int, kill_ns: int | None) -> None:
    """Every read of one case: time from the fault, truth, position, error, std, status bits."""
    slots, offsets = align(written, script.frames, reads, kill_ns)
    fault_ns = start_ns + int(script.fault_slot * SLOT_S * 1e9)
    print(f"trace of {case.name!r}: counter offsets {offsets}, fault at slot {script.fault_slot}")
    print(f"{'t-fault s':>9} {'slot':>6} {'truth m':>9} {'pos m':>9} {'error mm':>10} {'std mm':>9}  status")
    for r, k in zip(reads, slots, strict=False):
        if k < 0:
            continue
        status = StatusBits(r[4])
        names = "|".join(b.name for b in StatusBits if b in status)
        print(f"{(r[0] - fault_ns) / 1e9:9.3f} {k:6d} {script.ref_pos_m[k]:9.4f} {r[2]:9.4f} "
              f"{(r[2] - script.ref_pos_m[k]) * 1e3:10.2f} {r[3] * 1e3:9.2f}  {names}")


def dump_case(folder: Path, case: Case, written, reads, start_ns: int, kill_ns: int | None, log: Path) -> None:
    """One case's raw run: what --trace prints, kept to be studied after a long run."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = "".join(ch if ch.isalnum() else "_" for ch in case.name)
    np.savez(folder / f"{stem}.npz", written=written, reads=np.array(reads, dtype=float),
             start_ns=start_ns, kill_ns=-1 if kill_ns is None else kill_ns)
    (folder / f"{stem}.log").write_text(log.read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="", help="comma-separated substrings of case names (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trace", default="", metavar="NAME",
                    help="play the one case of this exact name and print every read instead of the table")
    ap.add_argument("--dump", default="", metavar="DIR",
                    help="also keep each case's writes, reads and daemon log in DIR (for --trace-like study)")
    args = ap.parse_args()
    if args.trace:
        case = next((c for c in all_cases() if c.name == args.trace), None)
        if case is None:
            raise SystemExit(f"--trace: no case named {args.trace!r}; names: "
                             + "; ".join(c.name for c in all_cases()))
        script = board_script(case, args.seed)
        with tempfile.TemporaryDirectory(prefix="adxlgw-fault-") as tmp:
            print_trace(case, script, *play(case, script, Path(tmp)))
        return
    cases = all_cases()
    if args.cases:
        wanted = [w.strip() for w in args.cases.split(",") if w.strip()]
        cases = [c for c in cases if any(w in c.name for w in wanted)]
        if not cases:
            raise SystemExit(f"--cases: no case matches {args.cases!r} (see the module doc for the names)")
    print(f"command: .venv/bin/python -m benchmarks.daemon.fault_benchmark"
          f"{f' --cases {args.cases!r}' if args.cases else ''} --seed {args.seed}")
    print(f"date:    {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    print("errors in mm (daemon − truth); at stops: the last read in each of the next "
          f"{STOPS_SCORED} true stops after the fault, V = VALID set there")
    print("| case | error at the next stops (mm) | VALID clear / UNTRUSTED set after the fault | VALID clear until a "
          "true stop (error when VALID again) | reads VALID with \\|error\\| > 5 mm "
          "| reads VALID with \\|error\\| > 3σ "
          "| \\|error\\| ≤ 3σ | goal met |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    covered = finite = 0
    for case in cases:
        script = board_script(case, args.seed)
        with tempfile.TemporaryDirectory(prefix="adxlgw-fault-") as tmp:
            written, reads, start_ns, kill_ns = play(case, script, Path(tmp))
            s = score(case, script, written, reads, start_ns, kill_ns)
            if args.dump:
                dump_case(Path(args.dump), case, written, reads, start_ns, kill_ns, Path(tmp) / "daemon.log")
            if s.reads == 0:
                print(f"| {case.name} | no read answered: see the daemon log | | | | | **no** |")
                print((Path(tmp) / "daemon.log").read_text()[-2000:], file=sys.stderr)
                continue
        covered += s.covered
        finite += s.finite
        print(row(case, s) + f" <!-- counter offsets {s.offsets}, {s.reads} reads -->", flush=True)
    if finite:
        print(f"coverage of the 3σ band over all cases: {100 * covered / finite:.2f} % of {finite} reads "
              f"(goal ≥ 99 %)")


if __name__ == "__main__":
    main()
