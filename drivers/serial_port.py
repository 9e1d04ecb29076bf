"""The board's serial port as settings and an opener: `SerialSettings` (the port, its line
settings, exclusive use, the reopening back-off, read sizes, the tty wakeup threshold),
`reconnect_delays_s` (the back-off schedule), `open_with_pyserial` (the default opener),
`SerialSourceState` (the snapshot a source reports) and the operator's text for an OS
error. The source that reads the port and survives its loss is drivers/serial_source.py."""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from dataclasses import dataclass

import serial


@dataclass(frozen=True)
class SerialSettings:
    #: Device path or pyserial URL.
    port: str
    baudrate: int = 115_200
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    #: flock() the device so a second gateway cannot silently share the board's bytes.
    exclusive: bool = True
    #: False: give up (raise) at the first loss instead of reconnecting (``record --once``).
    reconnect: bool = True
    reconnect_initial_s: float = 0.1
    reconnect_max_s: float = 5.0
    reconnect_multiplier: float = 2.0
    #: Most bytes handed out per read; the board sends ~7.5 kB/s.
    read_chunk_bytes: int = 4096
    #: Read timeout of the worker thread used for ports without a file descriptor (loop://).
    thread_poll_s: float = 0.05
    #: A tty is reported readable only once this many bytes wait (termios VMIN, 1–255);
    #: 1 wakes the reader at every arrival. No effect on pyserial URLs.
    wake_min_bytes: int = 1

    def __post_init__(self) -> None:
        if not self.port:
            raise ValueError("serial port must not be empty")
        if not 0 < self.reconnect_initial_s <= self.reconnect_max_s:
            raise ValueError("need 0 < reconnect_initial_s <= reconnect_max_s")
        if self.reconnect_multiplier < 1:
            raise ValueError("reconnect_multiplier must be >= 1")
        if self.read_chunk_bytes < 1 or self.thread_poll_s <= 0:
            raise ValueError("read_chunk_bytes and thread_poll_s must be positive")
        if not 1 <= self.wake_min_bytes <= 255:
            raise ValueError("wake_min_bytes must be within 1..255 (termios VMIN)")


def reconnect_delays_s(settings: SerialSettings) -> Iterator[float]:
    """The back-off schedule: initial, initial*multiplier, ... capped at reconnect_max_s."""
    delay = settings.reconnect_initial_s
    while True:
        yield delay
        delay = min(delay * settings.reconnect_multiplier, settings.reconnect_max_s)


@dataclass(frozen=True)
class SerialSourceState:
    """A snapshot for logs, health registers and tests."""

    port: str
    is_open: bool
    #: Calls to open the port, successful or not (first open included).
    open_attempts: int
    #: Successful opens after a loss.
    reconnects: int
    #: Times an open port failed on read (unplugged, hung up, EOF).
    losses: int
    #: Reads attempted on an open port (a loop that spins shows up here).
    reads: int
    bytes_read: int
    #: The most recent open or read error, kept after recovery for the operator.
    last_error: str | None
    #: time.monotonic() of the last byte received, None before the first one.
    last_data_monotonic_s: float | None


def _describe_os_error(err: BaseException) -> str:
    code = getattr(err, "errno", None)
    if isinstance(code, int) and code in errno.errorcode:
        text = f"{os.strerror(code)} [{errno.errorcode[code]}]"
        if code == errno.EACCES:
            text += " (does this user belong to the group owning the device, e.g. dialout?)"
        elif code in (errno.EBUSY, errno.EWOULDBLOCK):
            text += " (another process holds the port)"
        return text
    return str(err) or type(err).__name__


def open_with_pyserial(settings: SerialSettings) -> serial.SerialBase:
    """Default opener: pyserial, non-blocking reads (timeout=0), no flow control."""
    return serial.serial_for_url(
        settings.port,
        baudrate=settings.baudrate,
        bytesize=settings.bytesize,
        parity=settings.parity,
        stopbits=settings.stopbits,
        xonxoff=False,
        rtscts=False,
        dsrdtr=False,
        exclusive=settings.exclusive,
        timeout=0,
    )
