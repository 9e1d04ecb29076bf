"""A command run with its stderr on a pseudo-terminal: what a user at a terminal sees
(the progress bars of the long offline commands, gateway/offline/progress.py)."""
import os
import pty
import subprocess


def stderr_on_a_pty(cmd: list[str], timeout: float = 300) -> tuple[int, bytes]:
    """(exit code, every byte the command wrote to its stderr, a terminal)."""
    leader, follower = pty.openpty()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=follower)
    os.close(follower)
    seen = b""
    while True:
        try:
            data = os.read(leader, 4096)
        except OSError:  # EIO: the command closed its end
            break
        if not data:
            break
        seen += data
    code = proc.wait(timeout=timeout)
    os.close(leader)
    return code, seen
