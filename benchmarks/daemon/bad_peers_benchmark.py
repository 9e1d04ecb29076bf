"""Peers that try to hold the gateway, against the real daemon, shipped config (issue 31).

    .venv/bin/python -m benchmarks.daemon.bad_peers_benchmark [--root CHECKOUT ...]

`adxlgw run` of each checkout (default: this one) in a child process with the shipped
config but for the wires here: a pty as the board (nobody writes: Modbus serves anyway),
CAN off, Modbus TCP on a free port of 0.0.0.0, the open-file limit at systemd's default
1 024. From 127.0.0.2 (not a priority client: write_allow is 127.0.0.1), then:

- idle flood: 1 100 connections opened and left silent;
- slowloris: 200 connections that each complete one request and then stay silent (a
  client sending one request every 55 s, under the 60 s idle timeout, looks so between
  its requests);

and in each a PLC at 127.0.0.3 (not a priority client either) connects anew 28 times,
one read each: how many are answered within 2 s, and the slowest answer.
"""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import resource
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness
from benchmarks.daemon.service_timing import first_answer, free_port
from drivers.pty_port import PtyPort

ROOT = Path(__file__).resolve().parents[2]

READ = struct.pack(">HHHBBHH", 1, 0, 6, 1, 4, 0, 1)  # FC04, one input register
ATTACKER, PLC = "127.0.0.2", "127.0.0.3"
TRIES = 28
ANSWER_WITHIN_S = 2.0


def start_daemon(root: Path, tmp: Path) -> tuple[subprocess.Popen, int, PtyPort]:
    port = free_port()
    pty = PtyPort(tmp / f"board-{port}")
    config = tmp / f"gw-{port}.toml"
    config.write_text(f'[serial]\nport = "{pty.link}"\n[modbus]\nhost = "0.0.0.0"\nport = {port}\n'
                      f'[can]\nenabled = false\n[state]\npath = "{tmp / f"state-{port}.json"}"\n'
                      '[service]\nlog_level = "warning"\n')

    def limit_files() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (1024, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "run", "--config", str(config)], cwd=root,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=limit_files)
    if first_answer(port, time.monotonic() + 300) is None:
        proc.kill()
        raise SystemExit(f"{root}: the daemon never answered")
    return proc, port, pty


async def one_read(port: int, source: str) -> float | None:
    """Seconds to an answer on a new connection, None if none within ANSWER_WITHIN_S."""
    started = time.monotonic()
    try:
        reader, writer = await asyncio.wait_for(
            asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0)), ANSWER_WITHIN_S)
    except (TimeoutError, OSError):
        return None
    try:
        writer.write(READ)
        left = ANSWER_WITHIN_S - (time.monotonic() - started)
        answer = await asyncio.wait_for(reader.readexactly(11), max(left, 0.01))
        return time.monotonic() - started if answer else None
    except (TimeoutError, OSError, asyncio.IncompleteReadError):
        return None
    finally:
        writer.close()


async def attack(port: int, kind: str) -> tuple[int, float | None]:
    held = []
    count = 1100 if kind == "idle flood" else 200
    for _ in range(count):
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port, local_addr=(ATTACKER, 0))
        except OSError:
            continue
        if kind == "slowloris":
            writer.write(READ)
            with contextlib.suppress(TimeoutError, OSError, asyncio.IncompleteReadError):
                await asyncio.wait_for(reader.readexactly(11), 2.0)
        held.append(writer)
    await asyncio.sleep(0.5)
    answers = []
    for _ in range(TRIES):
        answers.append(await one_read(port, PLC))
        await asyncio.sleep(0.1)
    for writer in held:
        writer.close()
    got = [a for a in answers if a is not None]
    return len(got), (max(got) if got else None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", action="append", type=Path, help="a checkout whose daemon to run (repeatable)")
    args = ap.parse_args()
    roots = args.root or [ROOT]
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))  # the attacker's own sockets
    harness.stamp("benchmarks.daemon.bad_peers_benchmark")
    print(f"| daemon | attack | PLC reads answered within {ANSWER_WITHIN_S:g} s | slowest answer, s |")
    print("| --- | --- | --- | --- |")
    for root in roots:
        for kind in ("idle flood", "slowloris"):
            tmp = Path(tempfile.mkdtemp(prefix="adxlgw-peers-"))
            proc, port, pty = start_daemon(root, tmp)
            try:
                answered, slowest = asyncio.run(attack(port, kind))
            finally:
                proc.terminate()
                proc.wait(timeout=30)
                pty.close(remove_link=True)
            print(f"| {root} | {kind} | {answered} of {TRIES} | {'–' if slowest is None else f'{slowest:.3f}'} |",
                  flush=True)


if __name__ == "__main__":
    main()
