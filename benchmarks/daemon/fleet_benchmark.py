"""Fleet benchmark: N Sparkplug B edge nodes into one local mosquitto, the host view
reading all of them; and the daemon's CPU with MQTT on vs off, side by side.

    nice .venv/bin/python -m benchmarks.daemon.fleet_benchmark [--nodes 50] [--real 2] [--rate-hz 20]
        [--seconds 40] [--restart-at-s 15] [--cpu-seconds 20] [--cpu-rounds 3] [--probe-rounds 4] [--json FILE]

Part 1, the fleet. A mosquitto (persistence on, as a plant runs it) on a free loopback
port. `--real` edge nodes are real `adxlgw run` daemons (the built-in emulated board,
[mqtt] on, QoS 1); the rest are simulated edge nodes: the driver's own SparkplugNode,
all in one process, each replaying an estimate track (the realtime estimator run on
the simulator's strokes, seed 0, decimated to the rate; each node starts at its own
offset into it). The host is drivers/sparkplug_host.FleetListener with a persistent
session (QoS 1), as a historian would keep one. Halfway (`--restart-at-s`) the broker
is stopped as a service manager stops it (SIGTERM: it saves its sessions) and started
again 2 s later. Printed:
- messages/s received by the host, and DDATA made by the nodes;
- lost: DDATA a node made that the host never received, from the gap in each node's
  mqtt/ddata_count at the end (made − received − the node's own counted drops), total;
- end-to-end latency p50/p99 (payload timestamp → arrival at the host; one clock, ms
  resolution), for current data (outside the restart) and separately for the data
  sent late after it (flagged historical);
- broker CPU per message (utime+stime of mosquitto over the steady part, per message
  in, and per message in+out).

Part 2, daemon CPU at 500 samples/s. Two `adxlgw run` daemons at once, each with a
writer process playing the board on a real pty at 500 samples/s (as
benchmarks/daemon/daemon_benchmark.py does), one with [mqtt] on (20 Hz, QoS 1, to the
broker), one off; CPU % of one core from /proc over the run; `--cpu-rounds` rounds per
QoS (`--cpu-qos`, default 0 and 1), the roles' start order swapped each round; the
difference per round and its median.

Part 3, the node's own cost without a daemon's noise: an asyncio loop woken 100 times a
second (as the daemon is, once per batch of board samples), calling the node's poll()
at each wakeup or not, each in a fresh process, the two at the same time; `--probe-rounds`
rounds; CPU % and µs per DDATA, the difference's median and spread.

The machine is small and shared: the load average is printed at the start and the end.
Numbers go in commit messages and docs/mqtt.md with the command, date and machine line.
"""
from __future__ import annotations

import argparse
import asyncio
import atexit
import json
import multiprocessing as mp
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from benchmarks.daemon.daemon_benchmark import board_frames, cpu_seconds, pct, writer
from drivers.pty_port import PtyPort
from drivers.published_values import PublishedValues, StatusBits
from drivers.sparkplug_host import FleetListener
from testing.mqtt_helpers import Broker

ROOT = Path(__file__).resolve().parents[2]

GROUP = "bench"
#: Every daemon and broker this run started: ended at exit, whatever ended the run
STARTED: list = []


@atexit.register
def _end_what_was_started() -> None:
    for thing in STARTED:
        if isinstance(thing, Broker):
            thing.stop()
        elif thing.poll() is None:
            thing.kill()
            thing.wait()


# ------------------------------------------------------------------ estimates --
def estimate_snapshots(rate_hz: float) -> list[PublishedValues]:
    """The realtime estimator on the simulator's strokes (seed 0), one snapshot per 1/rate_hz."""
    from gateway.core.conversion import AxisCalibration, acceleration_mps2
    from gateway.core.estimator import estimate_series
    from gateway.core.estimator_settings import from_sensor_model
    from gateway.core.motion_profiles import StrokeSettings
    from gateway.core.scenarios import ScenarioSettings, build_profile
    from gateway.core.sensor_model import SensorParams
    from gateway.core.simulator import simulate

    run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=12))), seed=0)
    acc = acceleration_mps2(run.t1x, run.t2, AxisCalibration(0.5, 0.125))
    track = estimate_series(run.t_s, acc, method="realtime", settings=from_sensor_model(SensorParams()))
    step = max(1, int(round(1.0 / rate_hz / np.median(np.diff(track.t_s)))))
    snaps = []
    for k in range(0, len(track), step):
        status = StatusBits.VALID | (StatusBits.STANDSTILL if track.standstill[k] else 0)
        snaps.append(PublishedValues(position_m=float(track.pos_m[k]), velocity_mps=float(track.vel_mps[k]),
                                     acceleration_mps2=float(track.acc_mps2[k]),
                                     position_std_m=float(track.pos_std_m[k]),
                                     bias_estimate_mps2=float(track.bias_mps2[k]), status=StatusBits(status),
                                     sample_counter=k, last_sample_age_ms=2.0))
    return snaps


# ------------------------------------------------------------- simulated nodes --
def simulated_nodes(port: int, first: int, count: int, rate_hz: float, snaps, conn) -> None:
    """`count` SparkplugNodes in this process, each replaying the snapshots from its own
    offset, until told to stop through `conn` (then their counts go back through it)."""
    from drivers.sparkplug_node import SparkplugNode
    from drivers.sparkplug_settings import SparkplugSettings

    async def main():
        nodes = []
        for i in range(first, first + count):
            ticks = {"k": i * 37}

            def values(t=ticks):
                t["k"] += 1
                return snaps[t["k"] % len(snaps)]

            node = SparkplugNode(SparkplugSettings(port=port, group_id=GROUP, edge_node_id=f"node{i:03d}", qos=1,
                                                   rate_hz=rate_hz), values=values, version="bench",
                                 drive_itself=True)
            await node.start()
            nodes.append(node)
        await asyncio.to_thread(conn.recv)
        for node in nodes:
            await node.stop()
        conn.send({n.settings.edge_node_id: (n.counters.ddata_made, n.counters.dropped, n.counters.births)
                   for n in nodes})

    asyncio.run(main())


def real_daemon(tmp: Path, port: int, name: str, rate_hz: float, board: str = "emulated",
                qos: int = 1) -> subprocess.Popen:
    folder = tmp / name
    folder.mkdir(parents=True, exist_ok=True)
    config = folder / "gw.toml"
    mqtt = (f'[mqtt]\nenabled = true\nport = {port}\ngroup_id = "{GROUP}"\nedge_node_id = "{name}"\nqos = {qos}\n'
            f'rate_hz = {rate_hz}\n') if port else ""
    config.write_text(f'[serial]\nport = "{board}"\n[modbus]\nport = 0\n[can]\nenabled = false\n'
                      f'[state]\npath = "{folder / "state.json"}"\n[service]\nlog_level = "warning"\n{mqtt}')
    with open(folder / "stderr.log", "w") as stderr:  # the child keeps its own copy of the descriptor
        proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "run", "--config", str(config)], cwd=ROOT,
                                stdout=subprocess.DEVNULL, stderr=stderr)
    STARTED.append(proc)
    return proc


def scratch_dir(prefix: str) -> Path:
    """A private directory for brokers, daemons and ptys, removed when the benchmark exits."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


# ----------------------------------------------------------------- part 1 --
def fleet_run(args) -> dict:
    tmp = scratch_dir("adxlgw-fleet-")
    # a plant's broker for a historian: sessions kept across a restart, and room to queue
    # what arrives for the host while it reconnects (mosquitto's default: 1000 messages)
    broker = Broker(tmp, persistence=True, max_queued_messages=100_000).start()
    STARTED.append(broker)
    latencies: list[float] = []
    late: list[float] = []
    received: dict[str, int] = {}
    window = {"steady": False}

    def probe(message, arrived_s):
        if message.topic.kind != "DDATA":
            return
        node = message.topic.node
        received[node] = received.get(node, 0) + 1
        delay_ms = arrived_s * 1000 - message.payload.timestamp
        if any(m.historical for m in message.metrics):
            late.append(delay_ms)
        elif window["steady"]:
            latencies.append(delay_ms)

    host = FleetListener("127.0.0.1", broker.port, group=GROUP, client_id="bench-host", persistent=True,
                         ask_rebirth=False, on_message=probe)
    host.__enter__()
    if not host.connected.wait(30):
        raise SystemExit("the host could not connect")
    simulated = args.nodes - args.real
    ctx = mp.get_context("fork")
    snaps = estimate_snapshots(args.rate_hz)
    sims = []
    per = -(-simulated // args.sim_processes)
    for first in range(args.real, args.real + simulated, per):
        r, w = ctx.Pipe()
        count = min(per, args.real + simulated - first)
        p = ctx.Process(daemon=True, target=simulated_nodes,
                        args=(broker.port, first, count, args.rate_hz, snaps, w))
        p.start()
        sims.append((p, r))
    daemons = [real_daemon(tmp, broker.port, f"real{i}", args.rate_hz) for i in range(args.real)]

    def online() -> int:
        with host.lock:
            return sum(n.online for n in host.view.nodes.values())

    deadline = time.monotonic() + 180
    while online() < args.nodes:  # the real daemons take seconds to start on a loaded machine
        if time.monotonic() > deadline:
            raise SystemExit(f"only {online()} of {args.nodes} nodes born within 180 s")
        time.sleep(0.1)
    start = time.monotonic()

    def wait_until(t_s):
        while time.monotonic() - start < t_s:
            time.sleep(0.05)

    wait_until(2.0)
    window["steady"] = True
    cpu0, msgs0, t0 = cpu_seconds(broker.proc.pid), sum(received.values()), time.monotonic()
    wait_until(args.restart_at_s)
    cpu1, msgs1, t1 = cpu_seconds(broker.proc.pid), sum(received.values()), time.monotonic()
    window["steady"] = False
    broker.stop()
    time.sleep(2.0)
    broker.start()
    wait_until(args.restart_at_s + 8.0)
    window["steady"] = True
    wait_until(args.seconds - 1.0)
    window["steady"] = False
    sim_counts = {}
    for _, r in sims:
        r.send("stop")
    for p, r in sims:
        if not r.poll(60):
            raise SystemExit(f"simulated nodes did not report (exit code {p.exitcode})")
        sim_counts.update(r.recv())
        p.join()
    real_counts = {}
    death_seen_s = float("nan")
    for i, d in enumerate(daemons):
        if i == 0:  # kill -9: how long until the host sees its death (the broker's will)
            killed = time.monotonic()
            d.send_signal(signal.SIGKILL)
            d.wait(timeout=20)
            while time.monotonic() - killed < 60:
                with host.lock:
                    if not host.view.nodes[(GROUP, "real0")].online:  # (online before: all were born)
                        death_seen_s = time.monotonic() - killed
                        break
                time.sleep(0.01)
        else:
            d.send_signal(signal.SIGTERM)
            d.wait(timeout=20)
    time.sleep(2.0)  # the last messages reach the host
    with host.lock:
        for (_group, node), n in host.view.nodes.items():
            if node.startswith("real"):
                dev = n.devices.get("axis")
                real_counts[node] = (dev.last_count if dev else 0, 0, n.births)
    host.__exit__()
    broker.stop()
    counts = {**sim_counts, **real_counts}
    lost = {node: made - received.get(node, 0) - dropped for node, (made, dropped, _) in sim_counts.items()}
    with host.lock:
        view_lost = sum(d.lost for n in host.view.nodes.values() for d in n.devices.values())
    steady_msgs = msgs1 - msgs0
    return {
        "nodes": args.nodes, "real": args.real, "rate_hz": args.rate_hz,
        "host_messages_per_s": steady_msgs / (t1 - t0),
        "ddata_made": sum(c[0] for c in counts.values()),
        "ddata_received": sum(received.values()),
        "lost_simulated": sum(max(0, v) for v in lost.values()),
        "duplicates_simulated": sum(-min(0, v) for v in lost.values()),
        "lost_by_count_gaps": view_lost,
        "dropped_by_nodes": sum(c[1] for c in sim_counts.values()),
        "births_per_node_min": min(c[2] for c in counts.values()) if counts else 0,
        "latency_ms_p50": pct(latencies, 50), "latency_ms_p99": pct(latencies, 99),
        "latency_ms_max": float(max(latencies)) if latencies else float("nan"),
        "late_after_restart_n": len(late), "late_ms_p50": pct(late, 50), "late_ms_max": float(max(late)) if late else 0,
        "broker_cpu_us_per_msg_in": 1e6 * (cpu1 - cpu0) / max(1, steady_msgs),
        "broker_cpu_pct": 100 * (cpu1 - cpu0) / (t1 - t0),
        "death_seen_s": death_seen_s,
    }


# ----------------------------------------------------------------- part 2 --
def cpu_round(broker_port: int, seconds: float, mqtt_first: bool, qos: int) -> dict:
    tmp = scratch_dir("adxlgw-fleet-cpu-")
    ptys = {role: PtyPort(tmp / f"board-{role}") for role in ("on", "off")}
    roles = ("on", "off") if mqtt_first else ("off", "on")
    daemons = {role: real_daemon(tmp, broker_port if role == "on" else 0, f"cpu-{role}", 20.0,
                                 board=str(ptys[role].link), qos=qos) for role in roles}
    for role, pty in ptys.items():
        if not pty.wait_for_reader(180):  # a daemon starting on a loaded 2-core machine: tens of seconds
            raise SystemExit(f"daemon {role} never opened its board port")
    frames = board_frames(seconds)
    start_ns = time.monotonic_ns() + int(3e9)
    ctx = mp.get_context("fork")
    pipes, writers = {}, []
    for role in roles:
        r, s = ctx.Pipe(False)
        w = ctx.Process(target=writer, args=(ptys[role].master_fd, frames, start_ns, s))
        w.start()
        pipes[role] = r
        writers.append(w)
    while time.monotonic_ns() < start_ns:
        time.sleep(0.01)
    cpu0 = {role: cpu_seconds(d.pid) for role, d in daemons.items()}
    wall0 = time.monotonic()
    for r in pipes.values():
        r.recv()
    wall1 = time.monotonic()
    cpu1 = {role: cpu_seconds(d.pid) for role, d in daemons.items()}
    for w in writers:
        w.join()
    for d in daemons.values():
        d.send_signal(signal.SIGTERM)
        d.wait(timeout=20)
    for pty in ptys.values():
        pty.close(remove_link=True)
    return {role: 100 * (cpu1[role] - cpu0[role]) / (wall1 - wall0) for role in daemons}


def cpu_compare(args) -> dict:
    tmp = scratch_dir("adxlgw-fleet-cpu-")
    results = {}
    with Broker(tmp) as broker, FleetListener("127.0.0.1", broker.port, group=GROUP) as host:
        for qos in args.cpu_qos:
            rounds = [cpu_round(broker.port, args.cpu_seconds, k % 2 == 0, qos) for k in range(args.cpu_rounds)]
            diffs = [r["on"] - r["off"] for r in rounds]
            results[f"qos{qos}"] = {"rounds": rounds, "diff_points": diffs, "diff_median": float(np.median(diffs))}
        with host.lock:
            results["ddata_heard"] = sum(d.ddata for n in host.view.nodes.values() for d in n.devices.values())
    return results


# ----------------------------------------------------------------- part 3 --
def probe_process(port: int, poll: bool, qos: int, seconds: float, conn) -> None:
    """An asyncio loop woken 100 times a second (as the daemon is, per batch of samples),
    calling the node's poll() at each wakeup or not; its CPU over `seconds`."""
    import resource

    from drivers.sparkplug_node import SparkplugNode
    from drivers.sparkplug_settings import SparkplugSettings

    snaps = estimate_snapshots(20.0)

    async def main():
        k = {"i": 0}

        def values():
            k["i"] += 1
            return snaps[k["i"] % len(snaps)]

        node = SparkplugNode(SparkplugSettings(port=port, group_id=GROUP, edge_node_id=f"probe-{poll}", qos=qos),
                             values=values)
        await node.start()

        async def wakeups():
            while True:
                await asyncio.sleep(0.01)
                if poll:
                    node.poll()

        task = asyncio.create_task(wakeups())
        await asyncio.sleep(3.0)
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
        sent0 = node.counters.ddata_sent
        await asyncio.sleep(seconds)
        r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
        cpu_s = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
        conn.send((100 * cpu_s / (t1 - t0), node.counters.ddata_sent - sent0))
        task.cancel()
        await node.stop()

    asyncio.run(main())


def node_probe(args) -> dict:
    """`--probe-rounds` rounds per QoS; in each, the polling and the idle process run at the
    same time (side by side: the machine's load, shared with other work, is the same for both)."""
    tmp = scratch_dir("adxlgw-fleet-probe-")
    ctx = mp.get_context("fork")
    out = {}
    with Broker(tmp) as broker:
        for qos in args.cpu_qos:
            pairs = []
            for _ in range(args.probe_rounds):
                started = {}
                for poll in (False, True):
                    r, w = ctx.Pipe(False)
                    p = ctx.Process(target=probe_process, args=(broker.port, poll, qos, args.probe_seconds, w))
                    p.start()
                    started["on" if poll else "off"] = (p, r)
                row = {role: r.recv() for role, (_, r) in started.items()}
                for p, _ in started.values():
                    p.join()
                pairs.append(row)
            diffs = [row["on"][0] - row["off"][0] for row in pairs]
            out[f"qos{qos}"] = {"rounds": pairs, "diff_points": diffs, "diff_median": float(np.median(diffs))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nodes", type=int, default=50)
    ap.add_argument("--real", type=int, default=2, help="of them real adxlgw run daemons")
    ap.add_argument("--rate-hz", type=float, default=20.0)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--restart-at-s", type=float, default=15.0)
    ap.add_argument("--cpu-seconds", type=float, default=20.0)
    ap.add_argument("--cpu-rounds", type=int, default=3)
    ap.add_argument("--cpu-qos", type=lambda t: [int(x) for x in t.split(",")], default=[0, 1],
                    help="the MQTT QoS values to compare, e.g. 0,1")
    ap.add_argument("--sim-processes", type=int, default=2, help="processes the simulated nodes share")
    ap.add_argument("--probe-seconds", type=float, default=20.0)
    ap.add_argument("--probe-rounds", type=int, default=4)
    ap.add_argument("--skip-fleet", action="store_true")
    ap.add_argument("--skip-probe", action="store_true")
    ap.add_argument("--skip-cpu", action="store_true")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args()
    harness.stamp("benchmarks.daemon.fleet_benchmark")
    print(f"mosquitto: {subprocess.run(['mosquitto', '-h'], capture_output=True, text=True).stdout.splitlines()[0]}; "
          f"load average (1, 5, 15 min): {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    results = {}
    if not args.skip_fleet:
        f = results["fleet"] = fleet_run(args)
        print(f"\nfleet: {f['nodes']} edge nodes ({f['real']} real adxlgw run, the rest simulated) at "
              f"{f['rate_hz']:g} Hz, QoS 1, broker restarted once")
        print(f"  host receives {f['host_messages_per_s']:.0f} messages/s (steady part)")
        print(f"  DDATA made {f['ddata_made']}, received {f['ddata_received']}; lost (simulated nodes, made − "
              f"received − dropped) {f['lost_simulated']}, duplicates {f['duplicates_simulated']}; gaps in "
              f"mqtt/ddata_count (all nodes) {f['lost_by_count_gaps']}; dropped by the nodes' queues "
              f"{f['dropped_by_nodes']}; fewest births of a node {f['births_per_node_min']}")
        print(f"  end-to-end latency (current data): p50 {f['latency_ms_p50']:.1f} ms, p99 "
              f"{f['latency_ms_p99']:.1f} ms, max {f['latency_ms_max']:.1f} ms")
        print(f"  sent late after the restart (historical): {f['late_after_restart_n']} messages, delay p50 "
              f"{f['late_ms_p50']:.0f} ms, max {f['late_ms_max']:.0f} ms")
        print(f"  broker CPU: {f['broker_cpu_pct']:.1f} % of one core, {f['broker_cpu_us_per_msg_in']:.0f} µs "
              f"per message received by the host")
        print(f"  kill -9 of a real daemon: the host saw its NDEATH after {f['death_seen_s']:.3f} s "
              f"(mqtt.keepalive_s 10: the bound is 15 s)")
    if not args.skip_cpu:
        c = results["cpu"] = cpu_compare(args)
        print("\ndaemon CPU at 500 samples/s, % of one core, MQTT on (20 Hz) vs off, side by side:")
        for qos in args.cpu_qos:
            q = c[f"qos{qos}"]
            for k, r in enumerate(q["rounds"]):
                print(f"  QoS {qos} round {k + 1}: on {r['on']:.2f} %, off {r['off']:.2f} %, "
                      f"difference {r['on'] - r['off']:+.2f} points")
            print(f"  QoS {qos}: median difference {q['diff_median']:+.2f} points")
        print(f"  (DDATA heard by the host from the 'on' daemons: {c['ddata_heard']})")
    if not args.skip_probe:
        pr = results["probe"] = node_probe(args)
        print("\nthe node alone: an asyncio loop woken 100 times a second, polling the node (20 Hz) or not, "
              "both at once, % of one core:")
        for qos in args.cpu_qos:
            q = pr[f"qos{qos}"]
            for row in q["rounds"]:
                (on, sent), (off, _) = row["on"], row["off"]
                print(f"  QoS {qos}: on {on:.2f} % ({sent} DDATA), off {off:.2f} %, difference {on - off:+.2f} points"
                      f" ({1e4 * (on - off) / max(1, sent / args.probe_seconds):.0f} µs per DDATA)")
            print(f"  QoS {qos}: median difference {q['diff_median']:+.2f} points "
                  f"(spread {min(q['diff_points']):+.2f} … {max(q['diff_points']):+.2f})")
    print(f"\nload average at the end (1, 5, 15 min): {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
