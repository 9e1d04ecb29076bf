"""The gateway's own work per board sample: hot in a loop, and as it runs in the flow.

    PYTHONPATH=. .venv/bin/python benchmarks/daemon_hot_path.py [--seconds 8]

Explains the CPU number of daemon_benchmark.py. One Gateway in this process (Modbus on
a free port, CAN on the python-can virtual bus):

- hot: SamplePipeline.feed (the daemon's whole sample path: decode, time, convert,
  estimate) fed the paper's SAMPLE frames back to back (µs per sample), one frame per
  call and five per call (a batch of the default config); then the values snapshot
  built and both cyclic CAN frames encoded (µs per cycle). What the code costs with
  everything in cache.
- in the flow: a gateway reading a real pty while a writer process plays the board at
  500 samples/s; this process's main-thread CPU per sample (the event loop's wakeup,
  the batches and the CAN cycles included).
"""
from __future__ import annotations

import argparse
import asyncio
import datetime
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
from drivers.can_frames import CyclicEncoder  # noqa: E402
from drivers.pty_port import PtyPort  # noqa: E402
from gateway.config import validate  # noqa: E402
from gateway.core.conversion import Calibration  # noqa: E402
from gateway.core.estimator_settings import from_sensor_model  # noqa: E402
from gateway.daemon import Gateway  # noqa: E402
from gateway.daemon.board_intake import BoardIntake  # noqa: E402
from gateway.daemon.sample_pipeline import SamplePipeline  # noqa: E402
from gateway.daemon.status_flags import LinkHealth  # noqa: E402

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=8.0, help="measured board time in the flow")
    args = ap.parse_args()
    frames = board_frames(args.seconds + 4.0)
    # the writer is forked before any event loop or thread exists in this process
    pty = PtyPort(Path(tempfile.mkdtemp(prefix="adxlgw-hot-")) / "board")
    start_ns = time.monotonic_ns() + int(15e9)  # the gateway starts (numba cache) and opens the pty first
    ctx = mp.get_context("fork")
    _, sent = ctx.Pipe(False)  # the writer's timestamps are not needed here
    board = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, sent))
    board.start()
    hot_sample_us, hot_batched_us, hot_cycle_us = hot(frames)
    flow_cpu_us, samples = asyncio.run(in_flow(pty, args.seconds, start_ns))
    board.terminate()  # it may still be writing the spare frames, with nobody reading
    board.join()
    pty.close(remove_link=True)
    print(f"command: PYTHONPATH=. .venv/bin/python benchmarks/daemon_hot_path.py --seconds {args.seconds:g}"
          " (ADXLGW_NO_JIT=1 in front: the same code as plain Python)")
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    print(f"hot:         SamplePipeline.feed {hot_sample_us:.1f} µs per sample one by one, {hot_batched_us:.1f} µs "
          f"in fives; snapshot + CAN frames encoded {hot_cycle_us:.1f} µs per cycle")
    print(f"in the flow: main-thread CPU {flow_cpu_us:.0f} µs per sample ({samples} samples at 500/s; "
          "wakeups, batches, CAN cycles included)")


if __name__ == "__main__":
    main()
