"""Private temporary directories that a killed process does not leave behind for good.

A process holds an flock(2) on its directory while it lives. SIGKILL runs no cleanup, so
the directory stays; the next process that makes one with the same prefix removes every
such directory whose lock is free — the kernel drops a dead process's locks, so a free
lock is proof that the owner is gone, not a guess. (The emulated board's link directory,
gateway/daemon/emulated_board.py, and the demo's state directory, gateway/commands/demo.py.)
"""
from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

log = logging.getLogger(__name__)

#: A directory younger than this may be one a starting process has made and not yet
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


def remove_stale_dirs(prefix: str, root: str | None = None, min_age_s: float = STALE_AFTER_S) -> list[Path]:
    """Remove this user's `prefix`* directories in `root` (the temp dir) whose owner is gone
    (their lock free); returns them."""
    removed = []
    now = time.time()
    for path in Path(root or tempfile.gettempdir()).glob(f"{prefix}*"):
        try:
            st = path.lstat()
            if not path.is_dir() or path.is_symlink() or st.st_uid != os.getuid() or now - st.st_mtime < min_age_s:
                continue
            fd = _locked_dir(str(path))
        except OSError:  # held by a live owner, or gone meanwhile
            continue
        try:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
        finally:
            os.close(fd)
    if removed:
        log.info("removed %d %s* directories left by killed processes", len(removed), prefix)
    return removed


class OwnedTempDir:
    """A private temporary directory, locked while this process lives; the stale ones of the
    same prefix removed first. A context manager; `cleanup()` is idempotent."""

    def __init__(self, prefix: str) -> None:
        remove_stale_dirs(prefix)
        self._dir = tempfile.TemporaryDirectory(prefix=prefix)
        self.name = self._dir.name
        self._lock_fd: int | None = _locked_dir(self.name)

    def cleanup(self) -> None:
        self._dir.cleanup()
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> str:
        return self.name

    def __exit__(self, *_exc: object) -> None:
        self.cleanup()
