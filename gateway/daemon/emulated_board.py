"""The built-in emulated board as a child process: `adxlgw emulate --loop` on a pty.

Used when the config says serial.port = "emulated" (the demo, and tests that want the
whole chain). The child is the same program a user would run by hand.

No orphans: the child's stdin is a pipe whose only writer is this process, and the
child stops when it reads the end of it (`--exit-with-stdin`). The kernel closes the
pipe however this process ends, SIGKILL included; a pipe, unlike PR_SET_PDEATHSIG,
needs no preexec_fn in a threaded parent and cannot miss a parent that died first.

No leftovers: the board's link lives in a private temporary directory that the gateway
holds an flock(2) on while it lives. A gateway killed by SIGKILL cannot remove it; the
next emulated board started on this machine removes every such directory whose lock is
free (its owner is gone) — the kernel drops a dead process's locks, so a free lock is
proof, not a guess.
"""
from __future__ import annotations

import asyncio
import contextlib
import fcntl
import logging
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from gateway.errors import DeviceError

log = logging.getLogger(__name__)

BOARD_DIR_PREFIX = "adxlgw-board-"
#: A directory younger than this may be one a starting gateway has made and not yet
#: locked (between mkdtemp and flock: microseconds): left alone.
STALE_AFTER_S = 60.0


def _locked_dir(path: str) -> int:
    """An fd of the directory holding its exclusive lock; OSError when another holds it."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise
    return fd


def remove_stale_board_dirs(root: str | None = None, min_age_s: float = STALE_AFTER_S) -> list[Path]:
    """Remove this user's emulated-board directories in `root` (the temp dir) whose owner
    is gone (their lock free); returns them."""
    removed = []
    now = time.time()
    for path in Path(root or tempfile.gettempdir()).glob(f"{BOARD_DIR_PREFIX}*"):
        try:
            st = path.lstat()
            if not path.is_dir() or path.is_symlink() or st.st_uid != os.getuid() or now - st.st_mtime < min_age_s:
                continue
            fd = _locked_dir(str(path))
        except OSError:  # held by a live gateway, or gone meanwhile
            continue
        try:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
        finally:
            os.close(fd)
    if removed:
        log.info("removed %d emulated-board directories left by killed gateways", len(removed))
    return removed


class EmulatedBoard:
    def __init__(self, seed: int = 0, extra_args: tuple[str, ...] = ()):
        self.seed = seed
        self.extra_args = extra_args
        self.proc: asyncio.subprocess.Process | None = None
        remove_stale_board_dirs()
        self._dir = tempfile.TemporaryDirectory(prefix=BOARD_DIR_PREFIX)
        self._lock_fd: int | None = _locked_dir(self._dir.name)  # ours while we live
        self.link = Path(self._dir.name) / "board"

    async def start(self) -> str:
        cmd = [sys.executable, "-m", "gateway.cli", "emulate", "--loop", "--seed", str(self.seed),
               "--link", str(self.link), "--exit-with-stdin", *self.extra_args]
        self.proc = await asyncio.create_subprocess_exec(
            *cmd, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        # No time limit of its own: a child that dies ends the wait (EOF), a stop cancels
        # it, and under systemd TimeoutStartSec bounds it. A fixed 30 s was too short on
        # an emulated CPU (qemu without KVM: ~10x slower imports), and the daemon then
        # went on without a board (tests/test_systemd_vm.py found it).
        line = await self.proc.stdout.readline()
        if not line:
            await self.stop()
            raise DeviceError("the emulated board did not start")
        log.info("emulated board on %s (%s)", self.link, line.decode().strip())
        return str(self.link)

    async def stop(self) -> None:
        if self.proc and self.proc.returncode is None:
            self.proc.terminate()
            try:
                await asyncio.wait_for(self.proc.wait(), timeout=2)
            except TimeoutError:
                self.proc.kill()
                await self.proc.wait()
        self._dir.cleanup()
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._lock_fd)
            self._lock_fd = None
