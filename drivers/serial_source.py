"""Bytes from the board's serial port, surviving an unplugged adapter.

:class:`SerialSource` opens a device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``)
or any pyserial URL (``loop://``, ``socket://host:port``) and hands out whatever bytes
have arrived, without blocking its caller:

* ``read_available()`` never blocks; ``read(timeout_s=...)`` blocks at most
  ``timeout_s`` and suits a reader thread;
* ``async for chunk in source.chunks()`` waits in the event loop's reader
  (``loop.add_reader``) when the port has a file descriptor, else in one worker thread
  polling with a short timeout, so a coroutine never blocks on the port;
* ``await source.deliver(consume)`` does the same but calls ``consume(chunk)`` straight
  from the event loop's reader callback, with the descriptor registered once per open
  port. That is one wakeup and one ``read`` per arrival (or per batch, below) and no
  task switch: what the daemon uses, since at 500 frames/s the per-wakeup overhead is
  most of its CPU use (``chunks()`` registers and unregisters the reader, creates a
  future and resumes a task per chunk, and pyserial's ``read`` adds a ``select`` per
  call).

With ``SerialSettings(wake_min_bytes=N)`` a tty port (a device or a pty, not a URL)
is set up so that the kernel reports it readable only once N bytes are waiting
(termios VMIN, with VTIME 0): ``deliver()`` is then woken once per N bytes instead of
once per arrival, and hands them over as one chunk (Linux reads a tty 64 bytes at a
time, so that may take more than one read). ``read_pending()`` takes whatever has
arrived meanwhile, never blocking, for a caller that needs the newest bytes before the
wakeup comes.

When the port disappears (read fails or reports EOF: adapter unplugged, pty closed)
the source logs it, records it in :class:`SerialSourceState`, closes the port and
reopens it with exponential back-off until it is back. With
``SerialSettings(reconnect=False)`` (the ``record --once`` behaviour) it raises
:class:`~drivers.errors.SerialPortError` instead. A port that cannot be opened in the
first place always raises, naming the port and the OS error.

The settings, the back-off schedule, the default opener and the state record are in
drivers/serial_port.py.

One consumer at a time: the source is not meant to be read from two threads at once.
Stop a running ``chunks()`` by cancelling its task, then ``close()``; calling
``close()`` from the ``async for`` body also ends it. ``deliver()`` ends on ``close()``
from anywhere in the event loop's thread (``consume`` included). For a port without a
descriptor, bytes the worker thread reads after cancellation are dropped.
"""

from __future__ import annotations

import asyncio
import dataclasses
import fcntl
import logging
import os
import select
import struct
import termios
import time
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from typing import Any

import serial

from drivers.errors import SerialPortError
from drivers.serial_port import (
    SerialSettings,
    SerialSourceState,
    _describe_os_error,
    open_with_pyserial,
    reconnect_delays_s,
)

try:  # the POSIX serial class: its descriptor can be read with os.read directly
    from serial.serialposix import Serial as _PosixSerial
except ImportError:  # pragma: no cover - not on Linux
    _PosixSerial = None

logger = logging.getLogger(__name__)


class SerialSource:
    def __init__(
        self,
        settings: SerialSettings,
        *,
        opener: Callable[[SerialSettings], serial.SerialBase] = open_with_pyserial,
    ) -> None:
        self.settings = settings
        self._opener = opener
        self._port: serial.SerialBase | None = None
        self._fd: int | None = None
        #: The open port is a POSIX device whose descriptor deliver() reads with os.read.
        self._direct_fd = False
        self._wake_min_bytes = 1
        #: The running deliver(): (loop, descriptor, its end).
        self._delivery: tuple[asyncio.AbstractEventLoop, int, asyncio.Future[None]] | None = None
        self._wanted_open = False
        self._given_up = False
        self._delays: Iterator[float] = reconnect_delays_s(settings)
        self._next_attempt_s = 0.0
        self._open_attempts = 0
        self._reconnects = 0
        self._losses = 0
        self._reads = 0
        self._bytes_read = 0
        self._last_error: str | None = None
        self._last_data_s: float | None = None

    @classmethod
    def from_config(cls, section: Mapping[str, Any]) -> SerialSource:
        """Build from a config mapping whose keys are :class:`SerialSettings` field names."""
        known = {f.name for f in dataclasses.fields(SerialSettings)}
        unknown = set(section) - known
        if unknown:
            raise ValueError(f"unknown serial settings: {', '.join(sorted(unknown))}")
        return cls(SerialSettings(**section))

    @property
    def state(self) -> SerialSourceState:
        return SerialSourceState(
            port=self.settings.port,
            is_open=self._port is not None,
            open_attempts=self._open_attempts,
            reconnects=self._reconnects,
            losses=self._losses,
            reads=self._reads,
            bytes_read=self._bytes_read,
            last_error=self._last_error,
            last_data_monotonic_s=self._last_data_s,
        )

    @property
    def is_open(self) -> bool:
        """Same as ``state.is_open``, without building a snapshot (read per sample)."""
        return self._port is not None

    @property
    def wake_min_bytes(self) -> int:
        """How many bytes wake ``deliver()`` on the open port: ``settings.wake_min_bytes``
        where it could be set (a tty), else 1 (every arrival)."""
        return self._wake_min_bytes

    @property
    def last_data_monotonic_s(self) -> float | None:
        """Same as ``state.last_data_monotonic_s``, without building a snapshot."""
        return self._last_data_s

    # --- opening and closing ------------------------------------------------------------

    def open(self) -> None:
        """Open the port now; raise SerialPortError naming the port and the OS error."""
        if self._port is not None:
            return
        self._open_attempts += 1
        port_name = self.settings.port
        try:
            port = self._opener(self.settings)
        except (serial.SerialException, OSError, ValueError) as err:
            self._last_error = f"cannot open serial port {port_name!r}: {_describe_os_error(err)}"
            raise SerialPortError(self._last_error, port=port_name) from err
        self._port = port
        try:
            self._fd = port.fileno()
        except (OSError, AttributeError):  # loop:// and friends have no descriptor
            self._fd = None
        self._direct_fd = self._fd is not None and _PosixSerial is not None and isinstance(port, _PosixSerial)
        self._wake_min_bytes = 1
        if self._direct_fd and self.settings.wake_min_bytes > 1:
            self._set_wake_min_bytes(port_name)
        self._wanted_open = True
        self._given_up = False
        self._delays = reconnect_delays_s(self.settings)

    def _set_wake_min_bytes(self, port_name: str) -> None:
        # pyserial leaves VMIN = VTIME = 0 (readable at the first byte). With VMIN = N and
        # VTIME = 0 the tty line discipline reports readiness only once N bytes wait; a
        # non-blocking read still returns whatever is there (read_pending).
        assert self._fd is not None
        try:
            attrs = termios.tcgetattr(self._fd)
            attrs[6][termios.VMIN] = self.settings.wake_min_bytes
            attrs[6][termios.VTIME] = 0
            termios.tcsetattr(self._fd, termios.TCSANOW, attrs)
        except termios.error as err:  # not a tty after all: wake at every arrival
            logger.debug("%s: cannot set VMIN (%s); woken at every arrival", port_name, err)
            return
        self._wake_min_bytes = self.settings.wake_min_bytes

    def close(self) -> None:
        """Close on purpose (a chunks() loop then ends); the next read opens afresh."""
        self._wanted_open = False
        self._drop_port()

    def _drop_port(self) -> None:
        self._end_delivery()  # unregister the descriptor before it is closed (its number may be reused)
        port, self._port, self._fd = self._port, None, None
        self._direct_fd = False
        self._wake_min_bytes = 1
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError) as err:
                # Closing a vanished device can fail; the port is gone either way.
                logger.debug("closing %s failed: %s", self.settings.port, err)

    def __enter__(self) -> SerialSource:
        self.open()
        return self

    def __exit__(self, *_exc_info: object) -> None:
        self.close()

    def _lose(self, err: BaseException) -> None:
        self._losses += 1
        self._last_error = f"serial port {self.settings.port!r} lost: {_describe_os_error(err)}"
        self._drop_port()
        if not self.settings.reconnect:
            self._given_up = True
            logger.error("%s; not reconnecting", self._last_error)
            raise SerialPortError(self._last_error, port=self.settings.port) from err
        delay = next(self._delays)
        self._next_attempt_s = time.monotonic() + delay
        logger.warning("%s; reopening with back-off (first retry in %.2f s)", self._last_error, delay)

    def _reopen_if_due(self) -> None:
        if time.monotonic() < self._next_attempt_s:
            return
        try:
            self.open()
        except SerialPortError as err:
            delay = next(self._delays)
            self._next_attempt_s = time.monotonic() + delay
            logger.debug("%s; next retry in %.2f s", err, delay)
            return
        self._reconnects += 1
        logger.warning("serial port %r is back (reconnect %d)", self.settings.port, self._reconnects)

    def _ensure_usable(self) -> None:
        # The first read (or the first after close()) opens the port and, unlike a
        # reopen after a loss, raises if it cannot.
        if not self._wanted_open:
            self.open()
        if self._given_up:
            raise SerialPortError(self._last_error or "serial port lost", port=self.settings.port)

    # --- reading ---------------------------------------------------------------------------

    def read_available(self, max_bytes: int | None = None) -> bytes:
        """Whatever has arrived, up to max_bytes; b"" when nothing has or the port is away.

        Never blocks. While the port is lost, a call also tries to reopen it once the
        back-off delay has passed.
        """
        self._ensure_usable()
        if self._port is None:
            self._reopen_if_due()
            if self._port is None:
                return b""
        return self._read_now(max_bytes or self.settings.read_chunk_bytes)

    def bytes_waiting(self) -> int:
        """Bytes the port holds that nobody has read yet (FIONREAD); 0 when not open.

        How far the reader lags the line: with `wake_min_bytes` up to one batch waits
        here by design."""
        if self._fd is None:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(self._fd, termios.FIONREAD, b"\0" * 4))[0]
        except OSError:
            return 0

    def read_pending(self) -> bytes:
        """Whatever the port holds right now; b"" when nothing or the port is not open.

        Never blocks and never (re)opens the port: for a caller in the event loop that
        wants the newest bytes before ``deliver()`` is woken (see ``wake_min_bytes``).
        A failed read is a loss, as in ``deliver()``.
        """
        if self._port is None:
            return b""
        max_bytes = self.settings.read_chunk_bytes
        if not self._direct_fd:
            return self._read_now(max_bytes)
        return self._read_all(max_bytes)

    def _read_all(self, max_bytes: int, at_least: int | None = None) -> bytes:
        """Read until the port has nothing more (or `at_least` bytes were read): a tty
        hands out at most 64 bytes per read on Linux 5.11 and later."""
        parts = []
        got = 0
        while self._port is not None and (at_least is None or got < at_least):
            # not known to be readable: no bytes is not an end of file (VMIN 0 reads return 0)
            chunk = self._read_fd(max_bytes, readable=False)
            if not chunk:
                break
            parts.append(chunk)
            got += len(chunk)
        return parts[0] if len(parts) == 1 else b"".join(parts)

    def _read_now(self, max_bytes: int) -> bytes:
        assert self._port is not None
        self._reads += 1
        try:
            data = self._port.read(max_bytes)
        except (serial.SerialException, OSError) as err:
            # pyserial reports EIO (pty hung up), and EOF (device gone: readable but
            # empty) as SerialException; both mean the port is away.
            self._lose(err)
            return b""
        if data:
            self._bytes_read += len(data)
            self._last_data_s = time.monotonic()
        return data

    def read(self, max_bytes: int | None = None, timeout_s: float = 0.05) -> bytes:
        """Like read_available, but waits up to timeout_s for bytes (for a reader thread).

        While the port is lost it sleeps until the next reopen attempt (at most
        timeout_s), so a loop calling it does not spin.
        """
        self._ensure_usable()
        max_bytes = max_bytes or self.settings.read_chunk_bytes
        if self._port is None:
            wait_s = min(timeout_s, max(0.0, self._next_attempt_s - time.monotonic()))
            if wait_s > 0:
                time.sleep(wait_s)
            self._reopen_if_due()
            return b""
        if self._fd is not None:
            try:
                ready, _, _ = select.select([self._fd], [], [], timeout_s)
            except (OSError, ValueError) as err:
                self._lose(err)
                return b""
            return self._read_now(max_bytes) if ready else b""
        # No descriptor to wait on: let pyserial's own timeout do the waiting.
        port = self._port
        try:
            port.timeout = timeout_s
            first = port.read(1)
            port.timeout = 0
        except (serial.SerialException, OSError) as err:
            self._reads += 1
            self._lose(err)
            return b""
        self._reads += 1
        if not first:
            return b""
        self._bytes_read += 1
        self._last_data_s = time.monotonic()
        return first + (self._read_now(max_bytes - 1) if max_bytes > 1 and self._port is not None else b"")

    async def _open_first(self) -> None:
        """Open at the start of chunks()/deliver() (raises if it cannot). Opening may
        block (socket:// connects, a USB device settles): a worker thread does it."""
        if not self._wanted_open:
            await asyncio.to_thread(self.open)

    async def _port_ready(self) -> bool:
        """Wait until the port is open again after a loss (back-off; raises when
        ``reconnect`` is False); False once close() was called: chunks/deliver end."""
        while True:
            if not self._wanted_open:
                return False  # close() was called
            self._ensure_usable()
            if self._port is not None:
                return True
            await asyncio.sleep(max(0.0, self._next_attempt_s - time.monotonic()))
            await asyncio.to_thread(self._reopen_if_due)

    async def chunks(self) -> AsyncIterator[bytes]:
        """Yield non-empty chunks as they arrive, forever (or until the port is given up).

        Raises SerialPortError if the port cannot be opened at first, or when it is lost
        and ``reconnect`` is False.
        """
        await self._open_first()
        loop = asyncio.get_running_loop()
        while await self._port_ready():
            if self._fd is None:
                data = await asyncio.to_thread(self.read, None, self.settings.thread_poll_s)
            else:
                await _wait_readable(loop, self._fd)
                data = self.read_available()
                if not data and self._port is not None:
                    # Readable yet nothing to read and no error: do not let a quirky
                    # driver turn the reader into a busy loop.
                    await asyncio.sleep(self.settings.thread_poll_s)
            if data:
                yield data


    async def deliver(self, consume: Callable[[bytes], object]) -> None:
        """Call ``consume(chunk)`` with every non-empty chunk as it arrives, forever.

        The contract of :meth:`chunks` (reopens after a loss; raises SerialPortError if
        the port cannot be opened at first, or when it is lost and ``reconnect`` is
        False; ends when ``close()`` is called, also from ``consume``), but for a port
        with a descriptor ``consume`` runs inside the event loop's reader callback, which
        stays registered while the port is open. An exception from ``consume`` ends
        ``deliver()`` with that exception.
        """
        await self._open_first()
        loop = asyncio.get_running_loop()
        while await self._port_ready():
            if self._fd is None:
                data = await asyncio.to_thread(self.read, None, self.settings.thread_poll_s)
                if data:
                    consume(data)
                continue
            await self._deliver_while_open(loop, self._fd, consume)

    async def _deliver_while_open(
        self, loop: asyncio.AbstractEventLoop, fd: int, consume: Callable[[bytes], object]
    ) -> None:
        """Until this descriptor is dropped (port lost or closed): readable → read → consume."""
        ended: asyncio.Future[None] = loop.create_future()
        read = self._read_fd if self._direct_fd else self._read_now
        max_bytes = self.settings.read_chunk_bytes
        batch = self._wake_min_bytes
        failed: list[Exception] = []

        def on_readable() -> None:
            try:
                data = read(max_bytes)
                if data:
                    if len(data) < batch:
                        # woken with a whole batch waiting, handed part of it: Linux (5.11
                        # on) reads a tty through a 64-byte buffer, one buffer per read
                        data += self._read_all(max_bytes, batch - len(data))
                    consume(data)
            except Exception as err:  # SerialPortError (no reconnect), or consume failed
                failed.append(err)
                self._end_delivery()

        self._delivery = (loop, fd, ended)
        loop.add_reader(fd, on_readable)
        try:
            await ended  # resolved by _end_delivery: the port dropped, or a failure
        finally:
            self._end_delivery()
        if failed:
            raise failed[0]

    def _end_delivery(self) -> None:
        delivery, self._delivery = self._delivery, None
        if delivery is not None:
            loop, fd, ended = delivery
            loop.remove_reader(fd)
            if not ended.done():
                ended.set_result(None)

    def _read_fd(self, max_bytes: int, readable: bool = True) -> bytes:
        """os.read on a POSIX serial descriptor (that the loop reported `readable`).

        What pyserial's ``read`` does with timeout 0, minus its ``select`` and timeout
        objects: EAGAIN is nothing to read; an error, or end of file on a readable
        descriptor (a device that is gone), is a loss, reported as pyserial reports it.
        """
        assert self._fd is not None
        self._reads += 1
        try:
            data = os.read(self._fd, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as err:
            self._lose(serial.SerialException(f"read failed: {err}"))
            return b""
        if not data:
            if readable:
                self._lose(serial.SerialException(
                    "device reports readiness to read but returned no data (device disconnected?)"))
            return b""
        self._bytes_read += len(data)
        self._last_data_s = time.monotonic()
        return data


async def _wait_readable(loop: asyncio.AbstractEventLoop, fd: int) -> None:
    ready = loop.create_future()

    def on_readable() -> None:
        if not ready.done():
            ready.set_result(None)

    loop.add_reader(fd, on_readable)
    try:
        await ready
    finally:
        loop.remove_reader(fd)
