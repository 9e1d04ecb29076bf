"""Daemon benchmark: sample latency to Modbus and CAN, CPU use, Modbus client load.

    .venv/bin/python -m benchmarks.daemon.daemon_benchmark [--seconds 20] [--clients 0,10,25,50,75]
    .venv/bin/python -m benchmarks.daemon.daemon_benchmark --cpu-only [--repeat 3]

A writer process plays the board on a real pty: SAMPLE frames at 500 samples/s (the
paper's strokes), timestamping the moment the last byte of each frame is written
(CLOCK_MONOTONIC, shared by all processes; taken just before the write). The gateway runs as its own process.

- Modbus latency: a raw-socket Modbus TCP client polls SAMPLE_COUNTER back to back;
  sample k is "showing" when the counter first reads ≥ k+1. The poll round trip is
  part of the number (it is what a PLC sees) and is printed beside it.
- CAN latency: the gateway process is instrumented (benchmark only, never in the
  product): each ADXL_Position frame sent records its time and how many samples the
  gateway had processed, so the newest sample it carries is known. Two numbers:
  "carrying it" — for each sample that a frame carries as its newest, from the sample
  to the first such frame (the age of the data when it goes on the bus); "every
  sample" — for every sample, to the first frame that carries it or a newer one (with
  frames every 10 ms and samples every 2 ms, four in five samples are never sent on
  their own; this includes the wait for the next cycle). Measured in the default mode
  (10 ms, sync_to_updates), strictly cyclic (sync_to_updates = false) and send on
  update (min_interval_ms = 0); the frame intervals are printed too. These runs have
  no Modbus client (the back-to-back poller alone keeps one of two cores busy).
- CPU: utime+stime of the gateway process from /proc over the run, % of one core.
  Beside it, the floor: the CPU of a process that only reads the same stream from the
  same pty on an asyncio event loop (a reader callback, os.read, nothing else), woken
  at every frame — what any process pays on this machine to be woken 500 times a
  second. The gateway is woken once per serial.batch_frames (5) frames, so its own
  wakeups cost less than that floor; the rest is its work.
- Clients: N further Modbus TCP clients, each polling all input registers at 100 Hz
  (from 2 load processes), while the Modbus latency is measured again.

The machine is small and shared (2 cores); the load generator competes with the
gateway for them, so the client numbers are a lower bound for a dedicated host.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import platform
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from drivers.board_protocol import encode_hello, encode_sample_records, encode_status
from drivers.modbus_map import INPUT_SIZE, REGISTERS
from drivers.pty_port import PtyPort
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from testing.fault_cases import RATE_HZ

ROOT = Path(__file__).resolve().parents[2]

SAMPLE_COUNTER_ADDR = next(r.address for r in REGISTERS if r.name == "SAMPLE_COUNTER")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --------------------------------------------------------------------------- board
def board_frames(seconds: float) -> list[bytes]:
    strokes = max(2, int(seconds / 1.4) + 2)
    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=strokes))), seed=0)
    records = encode_sample_records(run.seq, run.t1x, run.t1y, run.t2, run.flags)
    return [records[k].tobytes() for k in range(min(len(run), int(seconds * RATE_HZ)))]


def writer(master_fd: int, frames: list[bytes], start_at_ns: int, conn, port: PtyPort | None = None) -> None:
    """Plays the board: HELLO, then one SAMPLE every 2 ms, STATUS each second.

    A slot may hold no bytes (the line is silent then: no STATUS either) or more than
    a SAMPLE (a HELLO before it). With `port`, a slot is dropped while nobody has the
    port open, as on a real line (a pty would buffer it for the next reader); its
    written time is then 0.
    """
    report = dict(tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)
    os.write(master_fd, encode_hello(uptime_s=0, **report))
    while time.monotonic_ns() < start_at_ns:
        time.sleep(0.001)
    written = np.zeros(len(frames), dtype=np.int64)
    period_ns = int(1e9 / RATE_HZ)
    for k, frame in enumerate(frames):
        due = start_at_ns + k * period_ns
        while True:
            now = time.monotonic_ns()
            if now >= due:
                break
            if due - now > 300_000:
                time.sleep((due - now - 200_000) / 1e9)
        # taken just before the write: the last byte is on the pty no earlier than this,
        # so latencies are never under-stated (a timestamp after os.write returns can
        # come after the gateway already answered, if the writer is preempted)
        if port is not None and not port.has_reader():
            continue
        written[k] = time.monotonic_ns()
        os.write(master_fd, frame)
        if k % 500 == 499 and frame:
            os.write(master_fd, encode_status(seq=k, uptime_s=k // 500, **report))
    conn.send(written)


# --------------------------------------------------------------------------- Modbus polling
def _read_request(tid: int, address: int, count: int) -> bytes:
    return struct.pack(">HHHBBHH", tid & 0xFFFF, 0, 6, 1, 4, address, count)


def counter_socket(port: int) -> socket.socket:
    """A raw Modbus TCP connection to the daemon (no client library in the timed loop)."""
    s = socket.create_connection(("127.0.0.1", port))
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def read_sample_counter(s: socket.socket, tid: int) -> tuple[int, int, int]:
    """One read of SAMPLE_COUNTER: (sent ns, answered ns, counter)."""
    t0 = time.monotonic_ns()
    s.sendall(_read_request(tid, SAMPLE_COUNTER_ADDR, 2))
    reply = b""
    while len(reply) < 13:
        reply += s.recv(64)
    return t0, time.monotonic_ns(), struct.unpack(">I", reply[9:13])[0]


def poll_sample_counter(port: int, until_ns: int, conn) -> None:
    """Back-to-back reads of SAMPLE_COUNTER: (time seen, counter) whenever it changes."""
    s = counter_socket(port)
    seen, rtts = [], []
    last = -1
    tid = 0
    while time.monotonic_ns() < until_ns:
        tid += 1
        t0, t1, counter = read_sample_counter(s, tid)
        rtts.append(t1 - t0)
        if counter != last:
            seen.append((t1, counter))
            last = counter
    s.close()
    conn.send((seen, rtts))


async def _client_load(port: int, clients: int, rate_hz: float, until: float, results: list) -> None:
    async def one(i: int) -> None:
        reader, writer_ = await asyncio.open_connection("127.0.0.1", port)
        n = 0
        next_t = time.monotonic() + (i / clients) / rate_hz
        while time.monotonic() < until:
            await asyncio.sleep(max(0.0, next_t - time.monotonic()))
            next_t += 1.0 / rate_hz
            writer_.write(_read_request(n, 0, INPUT_SIZE))
            await reader.readexactly(9 + 2 * INPUT_SIZE)
            n += 1
        writer_.close()
        results.append(n)

    await asyncio.gather(*(one(i) for i in range(clients)))


def client_load(port: int, clients: int, rate_hz: float, until_monotonic: float, conn) -> None:
    results: list[int] = []
    try:
        asyncio.run(_client_load(port, clients, rate_hz, until_monotonic, results))
        conn.send(("ok", sum(results)))
    except Exception as err:  # the report says how many requests got through
        conn.send((f"{type(err).__name__}: {err}", sum(results)))


# --------------------------------------------------------------------------- gateway child
CHILD = r"""
import asyncio, json, sys, time
from gateway.config import load_config
from gateway.daemon import Gateway

cfg = load_config({config!r})
sends = []

def timed_bus(**kwargs):
    # python-can's Bus, its sends timed: when each position frame left, and how many
    # samples the gateway had processed by then (the frame carries their values)
    import can
    bus = can.Bus(**kwargs)
    send = bus.send
    def timed_send(msg, timeout=None):
        send(msg, timeout)
        if msg.arbitration_id == 0x120:
            sends.append((time.monotonic_ns(), gw.pipeline.counters.samples))
    bus.send = timed_send
    return bus

gw = Gateway(cfg, can_bus_factory=timed_bus)

try:
    asyncio.run(gw.run())
finally:
    with open({trace!r}, "w") as fh:
        json.dump({{"sends": sends}}, fh)
"""


def start_gateway(tmp: Path, link: str, port: int, min_interval_ms: int, sync: bool, instrumented: bool,
                  max_connections: int = 64):
    config = tmp / "gw.toml"
    config.write_text(
        f'[serial]\nport = "{link}"\n[modbus]\nport = {port}\nmax_connections = {max_connections}\n'
        f'[can]\ninterface = "virtual"\nchannel = "bench"\nmin_interval_ms = {min_interval_ms}\n'
        f'sync_to_updates = {"true" if sync else "false"}\n'
        f'[state]\npath = "{tmp / "state.json"}"\n[service]\nlog_level = "warning"\n'
    )
    trace = tmp / "trace.json"
    if instrumented:
        code = CHILD.format(root=str(ROOT), config=str(config), trace=str(trace))
        argv = [sys.executable, "-c", code]
    else:
        argv = [sys.executable, "-m", "gateway.cli", "run", "--config", str(config)]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return proc, trace
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise SystemExit(f"gateway did not start: {proc.stderr.read()}")


FLOOR_READER = """
import asyncio, os, signal, tty

async def main():
    fd = os.open({link!r}, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    loop = asyncio.get_running_loop()
    done = loop.create_future()
    loop.add_signal_handler(signal.SIGTERM, done.set_result, None)
    loop.add_reader(fd, lambda: os.read(fd, 4096))
    await done

asyncio.run(main())
"""


def floor_run(seconds: float) -> float:
    """CPU % of a process that only reads the board's stream (see the module doc)."""
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-bench-"))
    pty = PtyPort(tmp / "board")
    code = FLOOR_READER.format(link=str(pty.link))
    reader = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT)
    if not pty.wait_for_reader(30):
        reader.kill()
        raise SystemExit("the floor reader never opened the pty")
    frames = board_frames(seconds)
    start_ns = time.monotonic_ns() + int(1e9)
    ctx = mp.get_context("fork")
    w_recv, w_send = ctx.Pipe(False)
    wproc = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, w_send))
    wproc.start()
    while time.monotonic_ns() < start_ns:
        time.sleep(0.01)
    cpu0, wall0 = cpu_seconds(reader.pid), time.monotonic()
    w_recv.recv()
    cpu1, wall1 = cpu_seconds(reader.pid), time.monotonic()
    wproc.join()
    reader.send_signal(signal.SIGTERM)
    reader.wait(timeout=10)
    pty.close(remove_link=True)
    return 100.0 * (cpu1 - cpu0) / (wall1 - wall0)


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def pct(values, q) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


def one_run(seconds: float, min_interval_ms: int, instrumented: bool, clients: int = 0, poll: bool = True,
            sync: bool = True):
    """Returns latencies (ms) to Modbus and CAN, CPU %, RTT, and client stats."""
    tmp = Path(tempfile.mkdtemp(prefix="adxlgw-bench-"))
    pty = PtyPort(tmp / "board")
    port = free_port()
    # the clients, the latency poller and a spare: above 64 (the default modbus.max_connections)
    # the server would refuse the load rather than serve it
    gw, trace = start_gateway(tmp, str(pty.link), port, min_interval_ms, sync, instrumented,
                              max_connections=max(64, clients + 2))
    if not pty.wait_for_reader(30):
        raise SystemExit("gateway never opened the board port")
    frames = board_frames(seconds)
    warmup_s = 2.0
    start_ns = time.monotonic_ns() + int(warmup_s * 1e9)
    end_ns = start_ns + int(len(frames) / RATE_HZ * 1e9) + int(0.3e9)
    ctx = mp.get_context("fork")
    w_recv, w_send = ctx.Pipe(False)
    p_recv, p_send = ctx.Pipe(False)
    wproc = ctx.Process(target=writer, args=(pty.master_fd, frames, start_ns, w_send))
    pproc = ctx.Process(target=poll_sample_counter, args=(port, end_ns if poll else 0, p_send))
    loaders = []
    for i in range(2 if clients else 0):
        share = clients // 2 + (clients % 2 if i == 0 else 0)
        r, s = ctx.Pipe(False)
        proc = ctx.Process(target=client_load, args=(port, share, 100.0, start_ns / 1e9 + len(frames) / RATE_HZ, s))
        loaders.append((proc, r))
    wproc.start()
    pproc.start()
    for proc, _ in loaders:
        proc.start()
    while time.monotonic_ns() < start_ns:
        time.sleep(0.01)
    cpu0, wall0 = cpu_seconds(gw.pid), time.monotonic()
    written = w_recv.recv()
    cpu1, wall1 = cpu_seconds(gw.pid), time.monotonic()
    seen, rtts = p_recv.recv()
    load = [r.recv() for _, r in loaders]
    for proc in (wproc, pproc, *(p for p, _ in loaders)):
        proc.join()
    gw.send_signal(signal.SIGTERM)
    gw.wait(timeout=10)
    pty.close(remove_link=True)

    # sample k (0-based in this run) is counted once the gateway has processed it; the
    # HELLO-less STATUS frames do not count, and the counter starts at 0
    seen_t = np.array([t for t, _ in seen], dtype=np.int64)
    seen_c = np.array([c for _, c in seen], dtype=np.int64)
    modbus_ms = []
    for k, w in enumerate(written):
        idx = np.searchsorted(seen_c, k + 1)
        if idx < len(seen_c):
            modbus_ms.append((seen_t[idx] - w) / 1e6)
    can_ms, carried_ms, interval_ms = [], [], []
    if instrumented:
        data = json.loads(trace.read_text())
        send_t = np.array([t for t, _ in data["sends"]], dtype=np.int64)
        send_count = np.maximum.accumulate(np.array([c for _, c in data["sends"]], dtype=np.int64))
        for k, w in enumerate(written):
            i = np.searchsorted(send_count, k + 1)  # the first frame carrying sample k or a newer one
            if i < len(send_t):
                can_ms.append((send_t[i] - w) / 1e6)
        # frames carrying a sample as their newest: the first frame with each new count
        first = np.flatnonzero(np.diff(send_count, prepend=0) > 0)
        for i in first:
            k = send_count[i] - 1
            if 0 <= k < len(written):
                carried_ms.append((send_t[i] - written[k]) / 1e6)
        during = send_t[(send_t >= written[0]) & (send_t <= written[-1])]
        interval_ms = list(np.diff(during) / 1e6)
    return {
        "modbus_ms": modbus_ms,
        "can_ms": can_ms,
        "carried_ms": carried_ms,
        "interval_ms": interval_ms,
        "cpu_pct": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
        "rtt_ms": [r / 1e6 for r in rtts],
        "samples": len(written),
        "client_requests": sum(n for _, n in load),
        "client_errors": [e for e, _ in load if e != "ok"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="board time per run")
    ap.add_argument("--clients", default="0,10,25,50,75", help="client counts for the load table")
    ap.add_argument("--cpu-only", action="store_true", help="only the CPU measurement (quick)")
    ap.add_argument("--repeat", type=int, default=1, help="with --cpu-only: runs, then median and range")
    args = ap.parse_args()
    if args.cpu_only:
        harness.stamp("benchmarks.daemon.daemon_benchmark")
        print(f"platform: {platform.platform()}")
        runs, floors = [], []
        for _ in range(args.repeat):  # interleaved: the machine's load drifts between runs
            runs.append(one_run(args.seconds, -1, instrumented=False, poll=False)["cpu_pct"])
            floors.append(floor_run(args.seconds))
            print(f"CPU at 500 samples/s: gateway, default config (CAN 10 ms), no Modbus "
                  f"client: {runs[-1]:.1f} % of one core; floor (a reader that does nothing): {floors[-1]:.1f} %",
                  flush=True)
        if len(runs) > 1:
            print(f"gateway: median {np.median(runs):.1f} %, range {min(runs):.1f}–{max(runs):.1f} %; "
                  f"floor: median {np.median(floors):.1f} %, range {min(floors):.1f}–{max(floors):.1f} % "
                  f"over {len(runs)} runs")
        return
    clients = [int(c) for c in args.clients.split(",")]
    harness.stamp("benchmarks.daemon.daemon_benchmark")
    print(f"platform: {platform.platform()}")
    print()
    print("latency from the last byte of a SAMPLE on the pty (500 samples/s):")
    print(f"{'path':58} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'n':>7}")
    plain = one_run(args.seconds, -1, instrumented=False)
    quiet = one_run(args.seconds, -1, instrumented=False, poll=False)
    # CAN without the back-to-back Modbus poller: on two cores it takes one by itself
    synced = one_run(args.seconds, -1, instrumented=True, poll=False)
    cyclic = one_run(args.seconds, -1, instrumented=True, poll=False, sync=False)
    eager = one_run(args.seconds, 0, instrumented=True, poll=False)
    modes = [
        ("default: 10 ms, sync_to_updates", synced),
        ("strictly cyclic 10 ms (sync_to_updates=false)", cyclic),
        ("send on update (min_interval_ms=0)", eager),
    ]
    rows = [("Modbus register (TCP poll, incl. round trip)", plain["modbus_ms"])]
    rows += [(f"CAN frame carrying it, {name}", run["carried_ms"]) for name, run in modes]
    rows += [(f"every sample to a CAN frame, {name}", run["can_ms"]) for name, run in modes]
    for name, values in rows:
        print(f"{name:58} {pct(values, 50):8.2f} {pct(values, 99):8.2f} {max(values, default=float('nan')):8.2f} "
              f"{len(values):7d}")
    print(f"  Modbus poll round trip: p50 {pct(plain['rtt_ms'], 50):.2f} ms, p99 {pct(plain['rtt_ms'], 99):.2f} ms")
    print("  ADXL_Position frame intervals:")
    for name, run in modes:
        gaps = run["interval_ms"]
        print(f"    {name:50} mean {np.mean(gaps):6.2f} ms, p1 {pct(gaps, 1):6.2f}, p99 {pct(gaps, 99):6.2f}, "
              f"max {max(gaps, default=float('nan')):6.2f}")
    print()
    print(f"CPU of the gateway at 500 samples/s, default config (CAN 10 ms), no Modbus client: "
          f"{quiet['cpu_pct']:.1f} % of one core")
    print(f"  (floor: a process that only reads the same stream: {floor_run(args.seconds):.1f} %)")
    print(f"  (with the back-to-back latency poller, {len(plain['rtt_ms']) / (plain['samples'] / RATE_HZ):.0f} "
          f"requests/s: {plain['cpu_pct']:.1f} %)")
    print()
    print("Modbus TCP clients polling all input registers at 100 Hz each:")
    print(f"{'clients':>7} {'req/s':>8} {'p50 ms':>8} {'p99 ms':>8} {'cpu %':>7}  errors")
    for n in clients:
        r = one_run(args.seconds, -1, instrumented=False, clients=n)
        rate = r["client_requests"] / (r["samples"] / RATE_HZ)
        print(f"{n:7d} {rate:8.0f} {pct(r['modbus_ms'], 50):8.2f} {pct(r['modbus_ms'], 99):8.2f} "
              f"{r['cpu_pct']:7.1f}  {'; '.join(r['client_errors']) or '-'}")


if __name__ == "__main__":
    main()
