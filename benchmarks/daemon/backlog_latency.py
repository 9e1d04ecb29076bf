"""How long a Modbus client waits for an answer while the daemon works through a backlog.

    .venv/bin/python -m benchmarks.daemon.backlog_latency [--stalls 1 4 8] [--no-jit-too]

The daemon (`adxlgw run`, a child) reads a board played on a pty (500 SAMPLE frames/s,
daemon_benchmark.writer) and a client polls SAMPLE_COUNTER back to back over Modbus TCP
(one request at a time, from another process). The daemon is stopped (SIGSTOP) for a
stall — a host that descheduled it — and continued: the tty then holds the stall's
samples (up to what the kernel buffers), and the request the client sent meanwhile waits
in its socket. A Modbus read takes every byte waiting in the port through the pipeline
before it answers (docs/decisions/0103: no wire shows older numbers than the port holds),
so its answer waits for that backlog's estimation, in one call on the event loop.

Printed per stall: the samples the first answer after the resume carried beyond the last
one before the stall, how long after the resume it came (ms; the work on the backlog plus
the loop's wakeup), and the longest wait of the requests after it (ms) beside the
longest of the quiet run before the stall. With `--no-jit-too` the same runs follow with
`ADXLGW_NO_JIT=1` (plain Python: the daemon's service on an emulated CPU, docs/daemon.md).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import signal
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.daemon.daemon_benchmark import (
    board_frames,
    counter_socket,
    free_port,
    read_sample_counter,
    start_gateway,
    writer,
)
from drivers.pty_port import PtyPort
from testing.fault_cases import RATE_HZ

QUIET_S = 3.0  # polled before the stall: the baseline
AFTER_S = 2.0  # polled after the resume


def poll(port: int, until_ns: int, conn) -> None:
    """Back-to-back reads of SAMPLE_COUNTER: (sent ns, answered ns, counter) of each."""
    s = counter_socket(port)
    rows = []
    tid = 0
    while time.monotonic_ns() < until_ns:
        tid += 1
        rows.append(read_sample_counter(s, tid))
    s.close()
    conn.send(rows)


def one_stall(stall_s: float) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-bench-"))
    pty = PtyPort(tmp / "board")
    port = free_port()
    gw, _ = start_gateway(tmp, str(pty.link), port, 0, True, False)
    try:
        if not pty.wait_for_reader(30):
            raise SystemExit("gateway never opened the board port")
        seconds = 1.0 + QUIET_S + stall_s + AFTER_S
        frames = board_frames(seconds)
        start_ns = time.monotonic_ns() + int(1e9)
        stop_at_ns = start_ns + int((1.0 + QUIET_S) * 1e9)
        end_ns = start_ns + int(len(frames) / RATE_HZ * 1e9)
        ctx = mp.get_context("fork")
        w_recv, w_send = ctx.Pipe(False)
        p_recv, p_send = ctx.Pipe(False)
        wproc = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, w_send))
        pproc = ctx.Process(target=poll, args=(port, end_ns, p_send))
        wproc.start()
        pproc.start()
        while time.monotonic_ns() < stop_at_ns:
            time.sleep(0.005)
        stopped_ns = time.monotonic_ns()
        gw.send_signal(signal.SIGSTOP)
        time.sleep(stall_s)
        resumed_ns = time.monotonic_ns()
        gw.send_signal(signal.SIGCONT)
        rows = p_recv.recv()
        w_recv.recv()
        wproc.join()
        pproc.join()
    finally:
        gw.send_signal(signal.SIGCONT)
        gw.terminate()
        gw.wait(timeout=30)
        pty.close(remove_link=True)
    quiet = [(a, b, c) for a, b, c in rows if start_ns + 1e9 <= a and b < stopped_ns]
    after = [(a, b, c) for a, b, c in rows if b > resumed_ns]
    first = after[0]
    return {
        "stall_s": stall_s,
        "samples_in_first_answer": first[2] - quiet[-1][2],
        "first_answer_after_resume_ms": (first[1] - resumed_ns) / 1e6,
        "longest_wait_after_ms": max((b - a) / 1e6 for a, b, _ in after[1:]),
        "longest_wait_quiet_ms": max((b - a) / 1e6 for a, b, _ in quiet),
    }


def main() -> None:
    parser = harness.parser(__doc__)
    parser.add_argument("--stalls", type=float, nargs="+", default=[1.0, 4.0, 8.0], help="stall lengths, s")
    parser.add_argument("--no-jit-too", action="store_true", help="also with ADXLGW_NO_JIT=1 (plain Python)")
    args = parser.parse_args()
    run = harness.stamp(__spec__.name)
    variants = [("numba", None)] + ([("plain Python", "1")] if args.no_jit_too else [])
    rows = []
    print(f"{'daemon':<13} {'stall s':>7} {'samples':>8} {'1st answer ms':>14} {'then max ms':>12} "
          f"{'quiet max ms':>13}")
    for name, no_jit in variants:
        if no_jit:
            os.environ["ADXLGW_NO_JIT"] = no_jit
        else:
            os.environ.pop("ADXLGW_NO_JIT", None)
        for stall_s in args.stalls:
            r = {"daemon": name, **one_stall(stall_s)}
            rows.append(r)
            print(f"{name:<13} {stall_s:>7g} {r['samples_in_first_answer']:>8d} "
                  f"{r['first_answer_after_resume_ms']:>14.1f} {r['longest_wait_after_ms']:>12.1f} "
                  f"{r['longest_wait_quiet_ms']:>13.1f}", flush=True)
    os.environ.pop("ADXLGW_NO_JIT", None)
    harness.write_json(args, {"rows": rows}, run)


if __name__ == "__main__":
    main()
