"""Shared parts of the CAN publisher tests: the DBC, a sample image, the PLC's side of a
virtual bus, and a publisher serving it."""
from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import can
import cantools

from drivers.can_publisher import CanPublisher, CanPublisherConfig
from drivers.published_values import PublishedValues, StatusBits, StatusExtBits

DBC_PATH = Path(__file__).resolve().parents[1] / "config" / "adxl-gateway.dbc"


DB = cantools.database.load_file(str(DBC_PATH))


VALUES = PublishedValues(
    position_m=0.731234,
    velocity_mps=-0.412345,
    acceleration_mps2=3.5,
    status=StatusBits.VALID | StatusBits.NOT_REFERENCED,
    position_std_m=0.004321,
    status_ext=StatusExtBits.HINT_AT_REST | StatusExtBits.STOP_BY_HINT,
)


class Peer:
    """The PLC's side of the bus: a second virtual bus on the same channel."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.reader = can.AsyncBufferedReader()
        self.notifier = can.Notifier(self.bus, [self.reader], timeout=0.05, loop=asyncio.get_running_loop())

    async def frames(self, count: int, frame_id: int | None = None, timeout_s: float = 5.0) -> list[can.Message]:
        found: list[can.Message] = []
        deadline = time.monotonic() + timeout_s
        while len(found) < count:
            remaining = deadline - time.monotonic()
            assert remaining > 0, f"got {len(found)} of {count} frames"
            message = await asyncio.wait_for(self.reader.get_message(), remaining)
            if frame_id is None or message.arbitration_id == frame_id:
                found.append(message)
        return found

    def send(self, frame_id: int, payload: bytes, extended: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=frame_id, data=payload, is_extended_id=extended))

    async def close(self) -> None:
        await asyncio.get_running_loop().run_in_executor(None, self.notifier.stop, 1.0)
        self.bus.shutdown()


@contextlib.asynccontextmanager
async def publishing(
    config: CanPublisherConfig,
    on_command: Callable | None = None,
    values: PublishedValues = VALUES,
    bus_factory: Callable = can.Bus,
) -> AsyncIterator[tuple[CanPublisher, Peer]]:
    peer = Peer(config.channel)  # listening before the first frame goes out
    publisher = CanPublisher(config, on_command, bus_factory=bus_factory)
    publisher.update(values)
    try:
        await publisher.start()
        yield publisher, peer
    finally:
        await publisher.stop()
        await peer.close()


def virtual_config(channel: str, **overrides) -> CanPublisherConfig:
    return CanPublisherConfig(**{"interface": "virtual", "channel": channel, **overrides})


def candump_line(channel: str, frame_id: int, payload: bytes) -> str:
    """One frame as `candump` prints it (what `cantools decode` reads)."""
    return f"  {channel}  {frame_id:03X}   [{len(payload)}]  " + " ".join(f"{b:02X}" for b in payload)


def cantools_decode(lines: list[str]) -> list[str]:
    """candump lines through `python -m cantools decode --single-line` with the shipped DBC:
    one decoded line per frame."""
    result = subprocess.run(
        [sys.executable, "-m", "cantools", "decode", "--single-line", str(DBC_PATH)],
        input="\n".join(lines) + "\n",
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return result.stdout.splitlines()
