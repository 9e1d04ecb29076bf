"""Private temporary directories (gateway/owned_tempdir.py): a process killed by SIGKILL
leaves its directory; the next one of the same prefix removes it — only if its owner is
gone (its lock free), never a live process's, never a young one (maybe not locked yet)."""
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from gateway.owned_tempdir import STALE_AFTER_S, OwnedTempDir, remove_stale_dirs

HOLDER = """
import sys, time
from gateway.owned_tempdir import OwnedTempDir
d = OwnedTempDir("adxlgw-test-")
print(d.name, flush=True)
time.sleep(600)
"""


def _holder(tmp_path: Path) -> tuple[subprocess.Popen, Path]:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp_path)})
    return proc, Path(proc.stdout.readline().strip())


def _age(path: Path) -> None:
    old = time.time() - 2 * STALE_AFTER_S
    os.utime(path, (old, old))


def test_a_killed_owners_directory_is_removed_by_the_next_and_a_living_ones_kept(tmp_path, monkeypatch):
    killed, left = _holder(tmp_path)
    living, kept = _holder(tmp_path)
    try:
        killed.kill()  # SIGKILL: no cleanup runs
        killed.wait(timeout=30)
        assert left.is_dir()
        _age(left)
        _age(kept)
        monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
        with OwnedTempDir("adxlgw-test-") as mine:
            assert not left.exists()  # its owner is gone: removed
            assert kept.is_dir()  # its owner lives: kept
            assert Path(mine).is_dir()
        assert not Path(mine).exists()
    finally:
        living.kill()
        living.wait(timeout=30)


def test_a_young_directory_is_left_alone(tmp_path):
    young = tmp_path / "adxlgw-test-young"
    young.mkdir()  # made, not yet locked: as a process between mkdtemp and flock
    assert remove_stale_dirs("adxlgw-test-", str(tmp_path)) == []
    _age(young)
    assert remove_stale_dirs("adxlgw-test-", str(tmp_path)) == [young]
