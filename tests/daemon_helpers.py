"""Shared parts of the daemon tests: the emulated board as a child process, a config,
the gateway in-process, and a Modbus client reading the register map."""
from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import time
import uuid
from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from drivers.modbus_map import INPUT_REGISTERS, INPUT_SIZE, WordOrder, decode_register
from gateway.config import validate

CLI = [sys.executable, "-m", "gateway.cli"]


class Emulator:
    """`adxlgw emulate` in its own process on a pty, behind a stable symlink."""

    def __init__(self, tmp_path: Path, *args: str):
        self.link = tmp_path / f"board-{uuid.uuid4().hex[:6]}"
        self.proc = subprocess.Popen([*CLI, "emulate", "--loop", "--link", str(self.link), *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = self.proc.stdout.readline()
        assert first, self.proc.stderr.read()

    def stop(self) -> str:
        self.proc.terminate()
        try:
            _, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        return err


def gateway_config(tmp_path: Path, port: str, **sections):
    data = {
        "serial": {"port": port, "stale_after_ms": 200, "lost_after_ms": 1000,
                   "reconnect_min_s": 0.05, "reconnect_max_s": 0.5},
        "modbus": {"port": 0, "writes_enabled": True},
        "can": {"interface": "virtual", "channel": f"gw-{uuid.uuid4().hex[:8]}", "commands_enabled": True},
        "state": {"path": str(tmp_path / "state.json")},
        # the emulated board starts at rest (a daemon that may start mid-move waits for evidence)
        "estimator": {"start_at_rest": True},
    }
    for name, table in sections.items():
        data.setdefault(name, {}).update(table)
    return validate(data, "<test>")


async def wait_for(predicate, timeout_s: float = 10.0, poll_s: float = 0.02, what: str = "condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        await asyncio.sleep(poll_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@contextlib.asynccontextmanager
async def running_gateway(cfg, **kwargs):
    from gateway.daemon import Gateway

    async with Gateway(cfg, **kwargs) as gw:
        await gw.wait_ready(30)
        yield gw


async def read_inputs(client: AsyncModbusTcpClient, word_order: WordOrder = WordOrder.ABCD) -> dict:
    rr = await client.read_input_registers(0, count=INPUT_SIZE)
    assert not rr.isError(), rr
    regs = rr.registers
    return {r.name: decode_register(r, regs[r.address:r.address + r.words], word_order) for r in INPUT_REGISTERS}


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(") ")[1][0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False
