"""Shared parts of the serial source tests: frames on the wire, a pty whose far end the test
holds, a consumer fed as the daemon feeds its decoder, and bounded waits."""
from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Callable

import pytest
import serial

from drivers.board_decoder import StreamDecoder
from drivers.board_protocol import Sample, encode
from drivers.serial_port import SerialSettings, reconnect_delays_s
from drivers.serial_source import SerialSource

DEADLINE_S = 10.0  # only a broken source needs this long


FAST_BACKOFF = dict(reconnect_initial_s=0.02, reconnect_max_s=0.16, reconnect_multiplier=2.0)


def frames(seqs: range) -> list[Sample]:
    return [Sample(s, 900 + s % 50, 930 - s % 40, 1843, 0) for s in seqs]


def wire(samples: list[Sample]) -> bytes:
    return b"".join(encode(s) for s in samples)


class Pty:
    """A pty pair; the slave path is what the source opens, the master plays the board."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        self.path = os.ttyname(self.slave)

    def unplug(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                os.close(fd)
        self.master = self.slave = -1


async def wait_until(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.005)


def max_attempts_within(settings: SerialSettings, elapsed_s: float) -> int:
    """Most reopen attempts the back-off schedule allows in elapsed_s after a loss."""
    total = 0.0
    for count, delay in enumerate(reconnect_delays_s(settings)):
        total += delay
        if total > elapsed_s:
            return count


class Consumer:
    """Feeds a decoder from ``source.deliver()`` (as the daemon does) or from
    ``async for chunk in source.chunks()``."""

    def __init__(self, source: SerialSource, mode: str = "deliver") -> None:
        self.source = source
        self.decoder = StreamDecoder()
        self.frames: list = []
        self.task = asyncio.create_task(self._deliver() if mode == "deliver" else self._chunks())

    def _consume(self, chunk: bytes) -> None:
        self.frames += self.decoder.feed(chunk)

    async def _deliver(self) -> None:
        await self.source.deliver(self._consume)

    async def _chunks(self) -> None:
        async for chunk in self.source.chunks():
            self._consume(chunk)

    async def stop(self) -> None:
        self.task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await self.task
        self.source.close()


READERS = pytest.mark.parametrize("mode", ["deliver", "chunks"])


class RecordingOpener:
    """pyserial's own opener, keeping the instance so the test can write into loop://."""

    def __init__(self) -> None:
        self.ports: list[serial.SerialBase] = []

    def __call__(self, settings: SerialSettings) -> serial.SerialBase:
        from drivers.serial_port import open_with_pyserial

        self.ports.append(open_with_pyserial(settings))
        return self.ports[-1]
