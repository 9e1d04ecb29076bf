"""The gateway's own work per board sample: hot in a loop, and as it runs in the flow.

    PYTHONPATH=. .venv/bin/python benchmarks/daemon_hot_path.py [--seconds 8]

Explains the CPU number of daemon_benchmark.py. One Gateway in this process (Modbus on
a free port, CAN on the python-can virtual bus):

- hot: Gateway.handle_frames fed the paper's SAMPLE frames back to back, CAN left out
  (µs per sample), one frame per call and five per call (a batch of Gateway.receive);
  then publish + one CAN cycle (values built, both frames encoded and sent) back to
  back (µs per cycle). What the code costs with everything in cache.
- in the flow: the same gateway reading a real pty while a writer process plays the
  board at 500 samples/s; Gateway.receive timed around each call (wall µs, it includes
  the batches it runs and the CAN cycles it sends), and this process's main-thread CPU
  per sample (the event loop's wakeup included).
"""
from __future__ import annotations

import argparse
import datetime
import asyncio
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.daemon_benchmark import board_frames, writer  # noqa: E402
from benchmarks.machine_info import machine  # noqa: E402
from drivers.board_protocol import encode_hello  # noqa: E402
from drivers.pty_port import PtyPort  # noqa: E402
from gateway.config import validate  # noqa: E402
from gateway.daemon import Gateway  # noqa: E402

HELLO = encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)


COMPILED_SAMPLES = True  # --python-samples: the Python path only (what it replaced)


def config(tmp: Path, port: str):
    return validate({"serial": {"port": port}, "modbus": {"port": 0},
                     "can": {"interface": "virtual", "channel": f"hot-{tmp.name}"},
                     "state": {"path": str(tmp / "state.json")}, "service": {"log_level": "error"}}, "<bench>")


async def hot(frames: list[bytes]) -> tuple[float, float]:
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-hot-"))
    # the port never opens: frames are fed by hand
    gw = Gateway(config(tmp, str(tmp / "no-board")), compiled_samples=COMPILED_SAMPLES)
    task = asyncio.create_task(gw.run())
    while gw.can is None:
        await asyncio.sleep(0.05)
    gw.handle_frames(HELLO)
    can, gw.can = gw.can, None
    t0 = time.perf_counter()
    for frame in frames:
        gw.handle_frames(frame)
    per_sample = (time.perf_counter() - t0) / len(frames)
    batches = [b"".join(frames[k:k + 5]) for k in range(0, len(frames), 5)]
    t0 = time.perf_counter()
    for batch in batches:
        gw.handle_frames(batch)
    per_sample_batched = (time.perf_counter() - t0) / len(frames)
    gw.can = can
    cycles = 2000
    t0 = time.perf_counter()
    for _ in range(cycles):
        gw.publish(gw.clock())
        can._send_cycle(0.0)
    per_cycle = (time.perf_counter() - t0) / cycles
    gw._stop.set()
    await task
    return per_sample * 1e6, per_sample_batched * 1e6, per_cycle * 1e6


async def in_flow(pty: PtyPort, seconds: float, start_ns: int) -> tuple[float, float, int]:
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-hot-"))
    gw = Gateway(config(tmp, str(pty.link)), compiled_samples=COMPILED_SAMPLES)
    spent = [0.0, 0]
    handle = gw.receive

    def timed(data: bytes) -> None:
        t = time.perf_counter()
        handle(data)
        spent[0] += time.perf_counter() - t
        spent[1] += 1

    gw.receive = timed  # before run(): the board task hands this to the port
    task = asyncio.create_task(gw.run())
    while (time.monotonic_ns() - start_ns) / 1e9 < 1.0:  # the first second after the writer starts
        await asyncio.sleep(0.05)
    samples0, spent[:] = gw.counters.samples, [0.0, 0]
    cpu0 = time.clock_gettime(time.CLOCK_THREAD_CPUTIME_ID)
    await asyncio.sleep(seconds)
    cpu = time.clock_gettime(time.CLOCK_THREAD_CPUTIME_ID) - cpu0
    samples = gw.counters.samples - samples0
    gw._stop.set()
    await task
    return spent[0] / max(spent[1], 1) * 1e6, cpu / max(samples, 1) * 1e6, samples


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=8.0, help="measured board time in the flow")
    ap.add_argument("--python-samples", action="store_true",
                    help="without the compiled per-chunk sample path (gateway/sample_fast_path.py)")
    args = ap.parse_args()
    global COMPILED_SAMPLES
    COMPILED_SAMPLES = not args.python_samples
    frames = board_frames(args.seconds + 4.0)
    # the writer is forked before any event loop or thread exists in this process
    pty = PtyPort(Path(tempfile.mkdtemp(prefix="adxlgw-hot-")) / "board")
    start_ns = time.monotonic_ns() + int(15e9)  # the gateway starts (numba cache) and opens the pty first
    ctx = mp.get_context("fork")
    _, sent = ctx.Pipe(False)  # the writer's timestamps are not needed here
    board = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, sent))
    board.start()
    hot_sample_us, hot_batched_us, hot_cycle_us = asyncio.run(hot(frames))
    flow_call_us, flow_cpu_us, samples = asyncio.run(in_flow(pty, args.seconds, start_ns))
    board.terminate()  # it may still be writing the spare frames, with nobody reading
    board.join()
    pty.close(remove_link=True)
    flag = " --python-samples" if args.python_samples else ""
    print(f"command: PYTHONPATH=. .venv/bin/python benchmarks/daemon_hot_path.py --seconds {args.seconds:g}{flag}")
    print(f"date: {datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')}; machine: {machine()}")
    print(f"hot:         handle_frames {hot_sample_us:.1f} µs per sample one by one, {hot_batched_us:.1f} µs "
          f"in fives (no CAN); publish + CAN cycle {hot_cycle_us:.1f} µs per cycle")
    print(f"in the flow: receive {flow_call_us:.1f} µs per call (batches and CAN cycles included); "
          f"main-thread CPU {flow_cpu_us:.0f} µs per sample ({samples} samples at 500/s)")


if __name__ == "__main__":
    main()
