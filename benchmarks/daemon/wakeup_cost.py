"""What being woken 500 times a second costs here, and what the gateway adds to it.

    .venv/bin/python -m benchmarks.daemon.wakeup_cost [--seconds 8] [--repeat 5]

Several readers of the board's stream run at the same time, each on its own pty with
its own writer process playing the board (500 SAMPLE frames/s, one write per frame,
as daemon_benchmark.py), so that all see the same state of the shared host — between
runs minutes apart it moves the numbers by more than the differences asked about.
CPU is utime+stime of each reader process over the run, % of one core:

- asyncio reader: an event loop with a reader callback that calls os.read — the
  floor of daemon_benchmark.py, what the gateway's loop pays per wakeup before work;
- thread reader: a plain blocking os.read loop, no event loop — what a dedicated
  board thread would pay;
- the gateway woken at every frame (serial.batch_frames = 1), without and with CAN
  (every 10 ms on python-can's virtual bus), and with its default config (woken once
  per 5 frames, termios VMIN; CAN on), no Modbus client;

and, after them, how long SamplePipeline.feed takes for the first chunk after a
wakeup compared with the same call on a second pipeline right after it (same code,
now in cache).

With `--compare DIR` (a checkout of another commit, e.g. `git worktree add /tmp/old
HEAD~5`), that checkout's gateway runs beside this one's with its default config, in the
same runs: a change measured side by side with the code before it. `--compare` may be
given several times (several commits, all in the same runs); `--gateways-only` leaves out
the thread reader and the gateways woken per frame, so that more checkouts fit on the
machine's cores beside the floor.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from benchmarks.daemon.daemon_benchmark import FLOOR_READER, board_frames, cpu_seconds, writer
from drivers.pty_port import PtyPort

ROOT = Path(__file__).resolve().parents[2]

THREAD_READER = """
import os, signal, tty
signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
fd = os.open({link!r}, os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
while True:
    os.read(fd, 4096)
"""

GATEWAY = """
import asyncio, sys, tempfile
from gateway.config import validate
from gateway.daemon import Gateway
tmp = tempfile.mkdtemp(prefix="adxlgw-wake-")
cfg = validate({{"serial": {{"port": {link!r}, "batch_frames": {batch}}}, "modbus": {{"port": 0}},
                 "can": {{"enabled": {can}, "interface": "virtual", "channel": "wake-" + tmp[-8:]}},
                 "state": {{"path": tmp + "/state.json"}}, "service": {{"log_level": "error"}}}}, "<bench>")
asyncio.run(Gateway(cfg).run())
"""

PROBE = """
import asyncio, os, signal, sys, tempfile, time, tty
from gateway.core.conversion import Calibration
from gateway.core.estimator_settings import from_sensor_model
from gateway.daemon.sample_pipeline import SamplePipeline

first, second = (SamplePipeline(Calibration(), from_sensor_model()) for _ in range(2))
spent = [0.0, 0.0, 0]
clock = time.perf_counter

def on_readable():
    data = os.read(fd, 4096)
    t0 = clock()
    first.feed(data)
    t1 = clock()
    second.feed(data)
    t2 = clock()
    spent[0] += t1 - t0
    spent[1] += t2 - t1
    spent[2] += 1

async def main():
    global fd
    fd = os.open({link!r}, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    loop = asyncio.get_running_loop()
    done = loop.create_future()
    loop.add_signal_handler(signal.SIGTERM, done.set_result, None)
    loop.add_reader(fd, on_readable)
    await done
    n = max(spent[2], 1)
    print(f"{{spent[0] / n * 1e6:.1f}} {{spent[1] / n * 1e6:.1f}} {{spent[2]}}", flush=True)
asyncio.run(main())
"""

VARIANTS = {
    "asyncio reader (the floor)": lambda link: FLOOR_READER.format(link=link),
    "thread reader (blocking os.read)": lambda link: THREAD_READER.format(link=link),
    "gateway, woken per frame, no CAN": lambda link: GATEWAY.format(root=str(ROOT), link=link, can=False, batch=1),
    "gateway, woken per frame": lambda link: GATEWAY.format(root=str(ROOT), link=link, can=True, batch=1),
    "gateway, default config": lambda link: GATEWAY.format(root=str(ROOT), link=link, can=True, batch=5),
}
PROBES = {
    "sample pipeline": lambda link: PROBE.format(root=str(ROOT), link=link),
}


def wakeups(pid: int) -> int:
    """Times the process's threads were put to sleep and woken again so far (voluntary
    context switches): each is one wakeup, whether Python ran after it or not."""
    total = 0
    for status in Path(f"/proc/{pid}/task").glob("*/status"):
        for line in status.read_text().splitlines():
            if line.startswith("voluntary_ctxt_switches:"):
                total += int(line.split()[1])
    return total


def together(codes: list, seconds: float, capture: bool = False) -> tuple[list[float], list[str], list[float]]:
    """Start every reader on its own pty, play the board to all at once; CPU % and
    wakeups per second of each."""
    readers = []
    for code in codes:
        pty = PtyPort(Path(tempfile.mkdtemp(prefix="adxlgw-wake-")) / "board")
        proc = subprocess.Popen([sys.executable, "-c", code(str(pty.link))], cwd=ROOT,
                                stdout=subprocess.PIPE if capture else subprocess.DEVNULL, text=True)
        readers.append((pty, proc))
    for pty, _proc in readers:
        if not pty.wait_for_reader(120):
            for _, p in readers:
                p.kill()
            raise SystemExit("a reader never opened its pty")
    frames = board_frames(seconds)
    start_ns = time.monotonic_ns() + int(2e9)  # the gateways are up (Modbus, CAN) by then
    ctx = mp.get_context("fork")
    writers = []
    for pty, _ in readers:
        done, sent = ctx.Pipe(False)
        w = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, sent))
        w.start()
        writers.append((done, w))
    while time.monotonic_ns() < start_ns:
        time.sleep(0.01)
    woken0 = [wakeups(p.pid) for _, p in readers]
    cpu0, wall0 = [cpu_seconds(p.pid) for _, p in readers], time.monotonic()
    for done, _ in writers:
        done.recv()
    cpu1, wall1 = [cpu_seconds(p.pid) for _, p in readers], time.monotonic()
    woken1 = [wakeups(p.pid) for _, p in readers]
    outputs = []
    for (_, w), (pty, proc) in zip(writers, readers, strict=False):
        w.join()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
        outputs.append(out or "")
        pty.close(remove_link=True)
    return ([100.0 * (b - a) / (wall1 - wall0) for a, b in zip(cpu0, cpu1, strict=False)], outputs,
            [(b - a) / (wall1 - wall0) for a, b in zip(woken0, woken1, strict=False)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--compare", metavar="DIR", action="append", default=[],
                    help="another checkout whose gateway runs beside this one's (may be repeated)")
    ap.add_argument("--gateways-only", action="store_true",
                    help="only the floor and the gateways with their default config")
    args = ap.parse_args()
    variants = dict(VARIANTS)
    if args.gateways_only:
        variants = {name: code for name, code in variants.items()
                    if name in ("asyncio reader (the floor)", "gateway, default config")}
    for other in args.compare:
        other_root = str(Path(other).resolve())
        variants[f"gateway @ {other}, default config"] = (  # root bound now, not at the loop's end
            lambda link, root=other_root: GATEWAY.format(root=root, link=link, can=True, batch=5))
    harness.stamp("benchmarks.daemon.wakeup_cost")
    names = list(variants)
    cpu = {name: [] for name in names}
    woken = {name: [] for name in names}
    for _ in range(args.repeat):
        got, _, rates = together([variants[n] for n in names], args.seconds)
        for name, value, rate in zip(names, got, rates, strict=False):
            cpu[name].append(value)
            woken[name].append(rate)
    print(f"CPU at 500 samples/s, one write per frame, {args.repeat} runs of {args.seconds:g} s, all side by side")
    print("(wakeups: voluntary context switches of all the process's threads):")
    for name in names:
        v = cpu[name]
        print(f"  {name:44s} median {np.median(v):4.1f} %   range {min(v):.1f}–{max(v):.1f} %   "
              f"wakeups {np.median(woken[name]):4.0f}/s")
    if args.compare:
        # the host's load moves all readers of one run together: each run's difference
        # to this checkout's gateway is steadier than the medians side by side
        here = np.array(cpu["gateway, default config"])
        print("each checkout's gateway minus this one's (default config), per run:")
        for name in names[-len(args.compare):]:
            d = np.array(cpu[name]) - here
            print(f"  {name:44s} median {np.median(d):+5.2f} points   range {d.min():+.2f}…{d.max():+.2f}   "
                  f"({int(np.sum(d < 0))} of {len(d)} runs below)")
    probe_names = list(PROBES)
    _, outs, _ = together([PROBES[n] for n in probe_names], args.seconds, capture=True)
    print("SamplePipeline.feed after each wakeup (µs per chunk, mean), and the same call on a second")
    print("pipeline right after it:")
    for name, out in zip(probe_names, outs, strict=False):
        first_us, second_us, calls = out.split()
        print(f"  {name:22s} first {float(first_us):5.1f} µs   second {float(second_us):5.1f} µs   ({calls} chunks)")


if __name__ == "__main__":
    main()
