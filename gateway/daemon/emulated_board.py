"""The built-in emulated board as a child process: `adxlgw emulate --loop` on a pty.

Used when the config says serial.port = "emulated" (the demo, and tests that want the
whole chain). The child is the same program a user would run by hand.

No orphans: the child's stdin is a pipe whose only writer is this process, and the
child stops when it reads the end of it (`--exit-with-stdin`). The kernel closes the
pipe however this process ends, SIGKILL included; a pipe, unlike PR_SET_PDEATHSIG,
needs no preexec_fn in a threaded parent and cannot miss a parent that died first.

No leftovers: the board's link lives in a private temporary directory that the gateway
holds a lock on while it lives (gateway/owned_tempdir.py): the next emulated board started
on this machine removes those whose owner was killed.
"""
from __future__ import annotations

import asyncio
import logging
import os
import sys
from pathlib import Path

from gateway.errors import DeviceError
from gateway.owned_tempdir import STALE_AFTER_S, OwnedTempDir, remove_stale_dirs

log = logging.getLogger(__name__)

BOARD_DIR_PREFIX = "adxlgw-board-"


def remove_stale_board_dirs(root: str | None = None, min_age_s: float = STALE_AFTER_S) -> list[Path]:
    """Remove this user's emulated-board directories in `root` (the temp dir) whose owner
    is gone (their lock free); returns them."""
    return remove_stale_dirs(BOARD_DIR_PREFIX, root, min_age_s)


class EmulatedBoard:
    def __init__(self, seed: int = 0, extra_args: tuple[str, ...] = ()):
        self.seed = seed
        self.extra_args = extra_args
        self.proc: asyncio.subprocess.Process | None = None
        self._dir = OwnedTempDir(BOARD_DIR_PREFIX)  # ours while we live; stale ones removed
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
        # went on without a board (tests/daemon/test_systemd_vm.py found it).
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
