"""A pseudo-terminal that looks like a serial port to whoever opens its slave side.

The emulated board writes to the master; a program that opens the slave path
(pyserial, minicom, the gateway) reads the board's bytes as from a USB adapter.
"""
from __future__ import annotations

import errno
import os
import select
import time
import tty
from pathlib import Path


class PtyPort:
    def __init__(self, link: str | os.PathLike | None = None):
        self.master_fd, slave_fd = os.openpty()
        # raw mode: no echo, no CR/LF translation, 8-bit clean — a serial line, not a console
        tty.setraw(slave_fd)
        self.slave_path = os.ttyname(slave_fd)
        # We do not keep the slave open: then the master reports POLLHUP exactly while
        # nobody has the port open, which tells the board whether anyone listens.
        os.close(slave_fd)
        self._poll = select.poll()
        self._poll.register(self.master_fd, select.POLLHUP)
        self.link = Path(link) if link else None
        if self.link:
            tmp = self.link.with_name(f".{self.link.name}.new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.slave_path)
            os.replace(tmp, self.link)  # atomic: a reader sees the old or the new port

    @property
    def path(self) -> str:
        return str(self.link) if self.link else self.slave_path

    def has_reader(self) -> bool:
        return not any(ev & select.POLLHUP for _, ev in self._poll.poll(0))

    def wait_for_reader(self, timeout_s: float | None = None, poll_s: float = 0.01) -> bool:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self.has_reader():
            if deadline is not None and time.monotonic() >= deadline:
                return False
            time.sleep(poll_s)
        return True

    def write(self, data: bytes, block: bool = True) -> int:
        """Write data; returns the bytes written.

        block=True waits while the reader is behind (the pty's buffer gives
        back-pressure). block=False behaves like a real line with nobody listening:
        what does not fit in the buffer is lost.
        """
        os.set_blocking(self.master_fd, block)
        view = memoryview(data)
        written = 0
        while written < len(view):
            try:
                written += os.write(self.master_fd, view[written:])
            except InterruptedError:
                continue
            except BlockingIOError:
                break
        return written

    def close(self, remove_link: bool = False) -> None:
        """Close both sides: a reader sees the port vanish (EIO / hang-up)."""
        try:
            os.close(self.master_fd)
        except OSError as err:
            if err.errno != errno.EBADF:
                raise
        self.master_fd = -1
        if remove_link and self.link:
            self.link.unlink(missing_ok=True)
