"""Python and C calls the gateway makes per batch of board samples, in the flow.

    .venv/bin/python -m benchmarks.tools.call_count [--checkout DIR] [--top 60]

A gateway in this process reads a real pty while a writer process plays the board at
500 samples/s (as benchmarks/tools/profile.py); for 3 s `sys.setprofile` counts every
call on the event loop's thread. Printed per batch of 5 samples (the default
serial.batch_frames): the total and the most frequent functions. A count, not a time:
on a VM each wakeup runs cold, and how much code a wakeup touches is what its CPU
follows (docs/daemon.md). `--checkout DIR` counts another commit's gateway (e.g. `git
worktree add /tmp/old 398284c`); gateways from before issue 12 had no public stop, so
the script cancels their run() after the count.
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import datetime
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

COUNT_S = 3.0
BATCH = 5


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkout", type=Path, default=Path(__file__).resolve().parents[2],
                    help="the checkout whose gateway to count (default: this one)")
    ap.add_argument("--top", type=int, default=60, help="functions listed")
    args = ap.parse_args()
    sys.path.insert(0, str(args.checkout.resolve()))
    from benchmarks.daemon.daemon_benchmark import board_frames, writer
    from benchmarks.harness import machine
    from benchmarks.tools.profile import config
    from drivers.pty_port import PtyPort
    from gateway.daemon import Gateway

    counts: collections.Counter[str] = collections.Counter()

    def profile(frame, event, arg) -> None:
        if event == "call":
            code = frame.f_code
            counts[f"{code.co_name} ({Path(code.co_filename).name})"] += 1
        elif event == "c_call":
            counts[f"C {getattr(arg, '__qualname__', arg)}"] += 1

    async def counted(gw) -> int:
        samples0 = gw.pipeline.counters.samples if hasattr(gw, "pipeline") else gw.counters.samples
        sys.setprofile(profile)
        await asyncio.sleep(COUNT_S)
        sys.setprofile(None)
        samples = gw.pipeline.counters.samples if hasattr(gw, "pipeline") else gw.counters.samples
        return samples - samples0

    async def flow(pty: PtyPort, start_ns: int) -> int:
        cfg = config(Path(tempfile.mkdtemp(prefix="adxlgw-calls-")), str(pty.link))
        if hasattr(Gateway, "__aenter__"):
            async with Gateway(cfg) as gw:
                await gw.wait_ready(60)
                while time.monotonic_ns() < start_ns + 1e9:
                    await asyncio.sleep(0.05)
                return await counted(gw)
        gw = Gateway(cfg)  # before issue 12: no public stop; its run() is cancelled after the count
        task = asyncio.create_task(gw.run())
        while time.monotonic_ns() < start_ns + 1e9:
            await asyncio.sleep(0.05)
        samples = await counted(gw)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        return samples

    frames = board_frames(COUNT_S + 8.0)
    pty = PtyPort(Path(tempfile.mkdtemp(prefix="adxlgw-calls-")) / "board")
    start_ns = time.monotonic_ns() + int(10e9)  # the gateway starts and opens the pty first
    ctx = mp.get_context("fork")
    _, sent = ctx.Pipe(False)
    board = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, sent))
    board.start()
    samples = asyncio.run(flow(pty, start_ns))
    board.terminate()
    board.join()
    pty.close(remove_link=True)
    print(f"command: .venv/bin/python -m benchmarks.tools.call_count --checkout {args.checkout}")
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    per_batch = BATCH / max(samples, 1)
    print(f"{samples} samples in {COUNT_S:g} s; calls per batch of {BATCH} samples: "
          f"{sum(counts.values()) * per_batch:.0f}")
    if samples < 0.95 * 500 * COUNT_S:
        print(f"  (not comparable: {samples} of {500 * COUNT_S:.0f} samples arrived — the writer or the "
              "gateway fell behind on a loaded host, and batches were not of 5)")
    for name, n in counts.most_common(args.top):
        print(f"  {n * per_batch:7.2f}  {name}")


if __name__ == "__main__":
    main()
