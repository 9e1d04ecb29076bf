"""The gateway's own work per board sample: hot in a loop, as it runs in the flow, and
the calls it makes per batch.

    .venv/bin/python -m benchmarks.tools.profile [--seconds 8]
    .venv/bin/python -m benchmarks.tools.profile --calls [--top 60] [--checkout DIR]

Explains the CPU number of benchmarks/daemon/daemon_benchmark.py. One Gateway in this
process (Modbus on a free port, CAN on the python-can virtual bus):

- hot: SamplePipeline.feed (the daemon's whole sample path: decode, time, convert,
  estimate) fed the paper's SAMPLE frames back to back (µs per sample), one frame per
  call and five per call (a batch of the default config); then the values snapshot
  built and both cyclic CAN frames encoded (µs per cycle). What the code costs with
  everything in cache.
- in the flow: a gateway reading a real pty while a writer process plays the board at
  500 samples/s; this process's main-thread CPU per sample (the event loop's wakeup,
  the batches and the CAN cycles included).
- `--calls`, instead: for 3 s of the flow `sys.setprofile` counts every call on the event
  loop's thread; printed per batch of 5 samples (the default serial.batch_frames): the
  total and the most frequent functions. A count, not a time: on a VM each wakeup runs
  cold, and how much code a wakeup touches is what its CPU follows (docs/daemon.md).

`--checkout DIR` profiles another commit's gateway (e.g. `git worktree add /tmp/old
398284c`): this module runs again in a child whose working directory is DIR, so DIR's
gateway and drivers are imported first (this checkout's benchmarks when DIR has no
benchmarks package); gateways from before issue 12 had no public stop, so their run() is
cancelled after the count.
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.daemon.daemon_benchmark import board_frames, writer
from drivers.board_protocol import encode_hello
from drivers.can_frames import CyclicEncoder
from drivers.pty_port import PtyPort
from gateway.config import validate
from gateway.core.conversion import Calibration
from gateway.core.estimator_settings import from_sensor_model
from gateway.daemon import Gateway
from gateway.daemon.board_intake import BoardIntake, LinkHealth
from gateway.daemon.sample_pipeline import SamplePipeline

ROOT = Path(__file__).resolve().parents[2]

#: Seconds of the flow whose calls are counted, and the samples per batch they are divided by.
COUNT_S = 3.0
BATCH = 5

HELLO = encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)


def config(tmp: Path, port: str):
    return validate({"serial": {"port": port}, "modbus": {"port": 0},
                     "can": {"interface": "virtual", "channel": f"hot-{tmp.name}"},
                     "state": {"path": str(tmp / "state.json")}, "service": {"log_level": "error"}}, "<bench>")


def hot(frames: list[bytes]) -> tuple[float, float, float]:
    def fresh() -> SamplePipeline:
        p = SamplePipeline(Calibration(), from_sensor_model())
        p.feed(HELLO)
        return p

    pipeline = fresh()
    t0 = time.perf_counter()
    for frame in frames:
        pipeline.feed(frame)
    per_sample = (time.perf_counter() - t0) / len(frames)
    batches = [b"".join(frames[k:k + 5]) for k in range(0, len(frames), 5)]
    pipeline = fresh()
    t0 = time.perf_counter()
    for batch in batches:
        pipeline.feed(batch)
    per_sample_batched = (time.perf_counter() - t0) / len(frames)
    intake = BoardIntake(pipeline)
    health = LinkHealth(port_open=True, last_byte_s=0.0, stale_after_s=0.2, lost_after_s=1.0)
    encoder = CyclicEncoder()
    cycles = 2000
    t0 = time.perf_counter()
    for k in range(cycles):
        intake.publish(float(k))
        encoder.encode(intake.snapshot(health), k % 15, k % 15)
    per_cycle = (time.perf_counter() - t0) / cycles
    return per_sample * 1e6, per_sample_batched * 1e6, per_cycle * 1e6


async def in_flow(pty: PtyPort, seconds: float, start_ns: int) -> tuple[float, int]:
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-hot-"))
    async with Gateway(config(tmp, str(pty.link))) as gw:
        await gw.wait_ready(60)
        while (time.monotonic_ns() - start_ns) / 1e9 < 1.0:  # the first second after the writer starts
            await asyncio.sleep(0.05)
        samples0 = gw.pipeline.counters.samples
        cpu0 = time.clock_gettime(time.CLOCK_THREAD_CPUTIME_ID)
        await asyncio.sleep(seconds)
        cpu = time.clock_gettime(time.CLOCK_THREAD_CPUTIME_ID) - cpu0
        samples = gw.pipeline.counters.samples - samples0
    return cpu / max(samples, 1) * 1e6, samples


class CallCounter:
    """Counts Python and C calls (sys.setprofile) while on."""

    def __init__(self) -> None:
        self.counts: collections.Counter[str] = collections.Counter()

    def _profile(self, frame, event, arg) -> None:
        if event == "call":
            code = frame.f_code
            self.counts[f"{code.co_name} ({Path(code.co_filename).name})"] += 1
        elif event == "c_call":
            self.counts[f"C {getattr(arg, '__qualname__', arg)}"] += 1

    async def count(self, gw, seconds: float) -> int:
        """Counts for `seconds`; the samples the gateway processed meanwhile."""
        def samples() -> int:
            return gw.pipeline.counters.samples if hasattr(gw, "pipeline") else gw.counters.samples

        samples0 = samples()
        sys.setprofile(self._profile)
        await asyncio.sleep(seconds)
        sys.setprofile(None)
        return samples() - samples0


async def calls_in_flow(pty: PtyPort, start_ns: int, counter: CallCounter) -> int:
    cfg = config(Path(tempfile.mkdtemp(prefix="adxlgw-calls-")), str(pty.link))
    if hasattr(Gateway, "__aenter__"):
        async with Gateway(cfg) as gw:
            await gw.wait_ready(60)
            while time.monotonic_ns() < start_ns + 1e9:
                await asyncio.sleep(0.05)
            return await counter.count(gw, COUNT_S)
    gw = Gateway(cfg)  # before issue 12: no public stop; its run() is cancelled after the count
    task = asyncio.create_task(gw.run())
    while time.monotonic_ns() < start_ns + 1e9:
        await asyncio.sleep(0.05)
    samples = await counter.count(gw, COUNT_S)
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task
    return samples


def with_board(seconds: float, lead_s: float, measure):
    """Runs `measure(pty, start_ns)` while a forked writer plays the board on a pty from
    `lead_s` from now (the gateway starts and opens the pty first)."""
    frames = board_frames(seconds)
    # the writer is forked before any event loop or thread exists in this process
    pty = PtyPort(Path(tempfile.mkdtemp(prefix="adxlgw-hot-")) / "board")
    start_ns = time.monotonic_ns() + int(lead_s * 1e9)
    ctx = mp.get_context("fork")
    _, sent = ctx.Pipe(False)  # the writer's timestamps are not needed here
    board = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, sent))
    board.start()
    try:
        return measure(frames, pty, start_ns)
    finally:
        board.terminate()  # it may still be writing the spare frames, with nobody reading
        board.join()
        pty.close(remove_link=True)


def print_calls(args: argparse.Namespace) -> None:
    counter = CallCounter()
    samples = with_board(COUNT_S + 8.0, 10.0,
                         lambda _frames, pty, start_ns: asyncio.run(calls_in_flow(pty, start_ns, counter)))
    harness.stamp("benchmarks.tools.profile")
    per_batch = BATCH / max(samples, 1)
    print(f"{samples} samples in {COUNT_S:g} s; calls per batch of {BATCH} samples: "
          f"{sum(counter.counts.values()) * per_batch:.0f}")
    if samples < 0.95 * 500 * COUNT_S:
        print(f"  (not comparable: {samples} of {500 * COUNT_S:.0f} samples arrived — the writer or the "
              "gateway fell behind on a loaded host, and batches were not of 5)")
    for name, n in counter.counts.most_common(args.top):
        print(f"  {n * per_batch:7.2f}  {name}")


def print_times(args: argparse.Namespace) -> None:
    def measure(frames, pty, start_ns):
        return hot(frames), asyncio.run(in_flow(pty, args.seconds, start_ns))

    # the gateway starts (numba cache) and opens the pty first
    (hot_sample_us, hot_batched_us, hot_cycle_us), (flow_cpu_us, samples) = with_board(args.seconds + 4.0, 15.0,
                                                                                        measure)
    harness.stamp("benchmarks.tools.profile")
    print("(ADXLGW_NO_JIT=1 in front of the command: the same code as plain Python)")
    print(f"hot:         SamplePipeline.feed {hot_sample_us:.1f} µs per sample one by one, {hot_batched_us:.1f} µs "
          f"in fives; snapshot + CAN frames encoded {hot_cycle_us:.1f} µs per cycle")
    print(f"in the flow: main-thread CPU {flow_cpu_us:.0f} µs per sample ({samples} samples at 500/s; "
          "wakeups, batches, CAN cycles included)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=8.0, help="measured board time in the flow")
    ap.add_argument("--calls", action="store_true", help="count the calls per batch instead of timing")
    ap.add_argument("--top", type=int, default=60, help="functions listed with --calls")
    ap.add_argument("--checkout", type=Path, help="profile this checkout's gateway (default: this one)")
    args = ap.parse_args()
    if args.checkout and args.checkout.resolve() != ROOT and os.environ.get("ADXLGW_PROFILE_CHILD") != "1":
        env = {**os.environ, "PYTHONPATH": str(ROOT), "ADXLGW_PROFILE_CHILD": "1"}
        return subprocess.run([sys.executable, "-m", "benchmarks.tools.profile", *sys.argv[1:]],
                              cwd=args.checkout.resolve(), env=env).returncode
    if args.calls:
        print_calls(args)
    else:
        print_times(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
