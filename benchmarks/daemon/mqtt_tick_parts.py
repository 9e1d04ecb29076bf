"""Where a due MQTT tick's CPU goes, in a real daemon: process-CPU timers around its parts.

    nice .venv/bin/python -m benchmarks.daemon.mqtt_tick_parts [--seconds 20] [--qos 0] [--json FILE]

One `adxlgw run` daemon with [mqtt] on (20 Hz) into a local mosquitto, no Modbus client,
CAN off, the board played on a pty at 500 samples/s (benchmarks/daemon/daemon_benchmark.py's
writer) — the case where the daemon builds its snapshot for the edge node alone. In the
daemon's process the parts of the node's tick are wrapped with a timer
(time.thread_time_ns before and after: CPU time, not wall time), and the counts and
totals printed when it stops. The parts nest: the node's tick holds the snapshot read
(Gateway.fresh_values: the LinkHealth, the estimate, the status words, the snapshot),
the device reading, the change set with the DDATA's encoding, and the socket write.
Each timer costs a few µs of its own, counted in the part it wraps and in the parts
around it: compare the parts of one run, or two runs of this command side by side, not
single numbers with other benchmarks'. On a VM every piece runs cold at each wakeup, several times its cost in a
hot loop (why: docs/decisions/0153-snapshot-and-ddata-cheap-per-tick.md).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.daemon.daemon_benchmark import board_frames, writer
from drivers.pty_port import PtyPort
from testing.mqtt_helpers import Broker

ROOT = Path(__file__).resolve().parents[2]

#: (what is timed, its owner as "module:Class" or "module", the function's name)
PARTS = (
    ("node tick", "drivers.sparkplug_node:SparkplugNode", "_tick"),
    ("  snapshot read (Gateway.fresh_values)", "gateway.daemon.supervisor:Gateway", "fresh_values"),
    ("    link health", "gateway.daemon.supervisor:Gateway", "_health"),
    ("    estimate", "gateway.daemon.sample_pipeline:SamplePipeline", "_build_latest"),
    ("  device reading", "drivers.sparkplug_payload", "device_reading"),
    ("  change set and DDATA encoding", "drivers.sparkplug_payload", "changed_device_data"),
    ("  socket write (QoS 0)", "drivers.sparkplug_node:SparkplugNode", "_send_direct"),
)


def _timed_daemon(config: str, out_path: str) -> None:
    """In the daemon's process: the parts wrapped, then `adxlgw run`; the totals written at its stop."""
    import importlib

    import gateway.commands.run as run_command

    totals: dict[str, list[int]] = {label: [0, 0] for label, _, _ in PARTS}

    def wrap(owner, name: str, label: str) -> None:
        inner = getattr(owner, name)
        tally = totals[label]

        def timed(*args, **kwargs):
            start_ns = time.thread_time_ns()
            try:
                return inner(*args, **kwargs)
            finally:
                tally[0] += 1
                tally[1] += time.thread_time_ns() - start_ns

        setattr(owner, name, timed)

    for label, where, name in PARTS:
        module_name, _, class_name = where.partition(":")
        module = importlib.import_module(module_name)
        wrap(getattr(module, class_name) if class_name else module, name, label)

    def stop(code: int) -> None:
        Path(out_path).write_text("\n".join(f"{label}\t{n}\t{ns}" for label, (n, ns) in totals.items()))
        os._exit(code)

    run_command.exit_now = stop  # (what `adxlgw run` ends with: here the totals first)
    from gateway.cli import main

    sys.argv = ["adxlgw", "run", "--config", config]
    main()


def run(seconds: float, qos: int) -> list[dict]:
    with tempfile.TemporaryDirectory(prefix="adxlgw-tick-parts-") as folder:  # (nothing left behind)
        return _run_in(Path(folder), seconds, qos)


def _run_in(tmp: Path, seconds: float, qos: int) -> list[dict]:
    with Broker(tmp) as broker:
        pty = PtyPort(tmp / "board")
        config = tmp / "gw.toml"
        config.write_text(f'[serial]\nport = "{pty.link}"\n[modbus]\nport = 0\n[can]\nenabled = false\n'
                          f'[state]\npath = "{tmp / "state.json"}"\n[service]\nlog_level = "warning"\n'
                          f'[mqtt]\nenabled = true\nport = {broker.port}\ngroup_id = "bench"\n'
                          f'edge_node_id = "parts"\nqos = {qos}\nrate_hz = 20\n')
        totals_path = tmp / "parts.tsv"
        daemon = subprocess.Popen([sys.executable, "-m", __spec__.name, "--timed-daemon", str(config),
                                   str(totals_path)], cwd=ROOT)
        try:
            if not pty.wait_for_reader(180):
                raise SystemExit("the daemon never opened its board port")
            start_ns = time.monotonic_ns() + int(3e9)
            ctx = mp.get_context("fork")
            done, send = ctx.Pipe(False)
            play = ctx.Process(target=writer, args=(pty.master_fd, board_frames(seconds), start_ns, send))
            play.start()
            done.recv()
            play.join()
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=60)
        finally:
            if daemon.poll() is None:
                daemon.kill()
                daemon.wait()
            pty.close(remove_link=True)
        rows = []
        for line in totals_path.read_text().splitlines():
            label, n, ns = line.split("\t")
            rows.append({"part": label, "calls": int(n), "us_per_call": int(ns) / 1e3 / max(1, int(n)),
                         "ms_total": int(ns) / 1e6})
        return rows


def main() -> None:
    if len(sys.argv) == 4 and sys.argv[1] == "--timed-daemon":
        _timed_daemon(sys.argv[2], sys.argv[3])
        return
    ap = harness.parser(__doc__)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--qos", type=int, default=0, choices=(0, 1))
    args = ap.parse_args()
    stamp = harness.stamp(__spec__.name)
    print(f"load average (1, 5, 15 min): {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    rows = run(args.seconds, args.qos)
    print(f"\nparts of the MQTT node's tick, daemon at 500 samples/s, 20 Hz, QoS {args.qos}, {args.seconds:g} s:")
    print(f"  {'part':42s} {'calls':>6s} {'µs per call':>12s} {'ms in all':>10s}")
    for r in rows:
        print(f"  {r['part']:42s} {r['calls']:6d} {r['us_per_call']:12.1f} {r['ms_total']:10.1f}")
    print(f"load average at the end (1, 5, 15 min): {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    harness.write_json(args, rows, stamp)


if __name__ == "__main__":
    main()
