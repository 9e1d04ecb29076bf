"""The board's serial port as the daemon keeps it: opened with back-off, read, reopened
when a reload changes its settings, closed — and the emulated board when the config
asks for it.

Each retry takes the config as it is then, so a reload that fixes `serial.port` while
the port is still missing is heard (issue 16).
"""
from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import Callable

from drivers.errors import SerialPortError
from drivers.serial_port import reconnect_delays_s
from drivers.serial_source import SerialSource
from gateway.config import Config
from gateway.daemon.emulated_board import EmulatedBoard
from gateway.daemon.settings import serial_settings_from

log = logging.getLogger("adxlgw")

READER_RESTART_S = 1.0  # a reader that ended on its own is started again after this


class BoardPort:
    def __init__(self, config: Callable[[], Config]):
        self._config = config  # the config in force, read anew at every (re)open
        self.source: SerialSource | None = None
        self.path: str | None = None
        self._emulated: EmulatedBoard | None = None
        self._emulated_start: asyncio.Task[str] | None = None
        self._reopen = asyncio.Event()

    @property
    def batches(self) -> bool:
        """The kernel wakes the reader per batch of frames (termios VMIN), not per byte."""
        return self.source is not None and self.source.wake_min_bytes > 1

    def read_pending(self) -> bytes:
        """The bytes waiting in the port now (never blocks; b"" when none or not open)."""
        return b"" if self.source is None else self.source.read_pending()

    def prepare(self) -> None:
        """Start now what opening the port will wait for: the emulated board's child (its
        imports and first frames take seconds — the demo showed "board None" that long),
        while the daemon loads its estimator."""
        if self._config().serial.port == "emulated" and self._emulated_start is None:
            rset_kohm = self._config().serial.emulated_rset_kohm
            self._emulated = EmulatedBoard(extra_args=("--rset-kohm", f"{rset_kohm:g}"))
            self._emulated_start = asyncio.create_task(self._emulated.start(), name="emulated-board")

    async def _board_path(self) -> str:
        port = self._config().serial.port
        if port != "emulated":
            return port
        self.prepare()
        return await self._emulated_start

    async def open(self) -> None:
        """Open the port, retrying with back-off (from the config of the moment)."""
        delays = None
        while True:
            path = await self._board_path()
            settings = serial_settings_from(self._config(), path)
            if self.source is None or self.source.settings != settings:
                if self.source is not None:
                    self.source.close()
                self.source = SerialSource(settings)
                self.path = path
                delays = reconnect_delays_s(settings)
            try:
                await asyncio.to_thread(self.source.open)
                log.info("board port %s open", self.path)
                return
            except SerialPortError as err:
                delay = next(delays)
                log.warning("%s; retrying in %.1f s", err, delay)
                await asyncio.sleep(delay)

    async def serve(self, consume: Callable[[bool, bytes], None]) -> None:
        """Hand every chunk to `consume(batched, data)` (in the loop's reader callback)
        until cancelled; reopen the port when `reopen()` was asked for. `batched`: the
        port's kernel wakes the reader per batch of frames (`batches`), known per open
        port and so told with each chunk rather than asked at every wakeup."""
        while True:
            self._reopen.clear()
            reader = asyncio.create_task(self.source.deliver(functools.partial(consume, self.batches)),
                                         name="board-reader")
            reopen = asyncio.create_task(self._reopen.wait())
            try:
                await asyncio.wait({reader, reopen}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                reader.cancel()
                reopen.cancel()
                await asyncio.gather(reader, reopen, return_exceptions=True)
            if reader.done() and not reader.cancelled() and reader.exception() is not None:
                log.error("board reader failed: %s", reader.exception())
            if self._reopen.is_set():
                self.source.close()
                await self.open()
            else:
                await asyncio.sleep(READER_RESTART_S)

    def reopen(self) -> None:
        """Close and open again with the config in force (a reload changed the port's settings)."""
        self._reopen.set()

    async def close(self) -> None:
        if self.source is not None:
            self.source.close()
        if self._emulated_start is not None and not self._emulated_start.done():
            self._emulated_start.cancel()
            await asyncio.gather(self._emulated_start, return_exceptions=True)
        if self._emulated is not None:
            await self._emulated.stop()
