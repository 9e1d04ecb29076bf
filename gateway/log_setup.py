"""Log lines on stderr that the journal files under the right priority.

Under systemd (StandardError=journal) each line the daemon writes becomes a journal
entry; a line that begins with an sd-daemon(3) prefix "<N>" gets priority N, so
`journalctl -p err -u adxl-gateway` finds the errors. systemd says which stream is
the journal with JOURNAL_STREAM=<device>:<inode>; a child whose stderr was
redirected inherits the variable but not the stream, hence the comparison
(systemd.exec(5), "Environment variables in spawned processes").
"""
from __future__ import annotations

import logging
import os
import sys
from collections.abc import Mapping
from typing import TextIO

# syslog priorities (sd-daemon(3)): 2 crit, 3 err, 4 warning, 5 notice, 6 info, 7 debug
_PRIORITIES = ((logging.CRITICAL, 2), (logging.ERROR, 3), (logging.WARNING, 4), (logging.INFO, 6))
PLAIN_FORMAT = "%(levelname)s %(name)s: %(message)s"


def sd_priority(levelno: int) -> int:
    for threshold, priority in _PRIORITIES:
        if levelno >= threshold:
            return priority
    return 7


def stream_is_journal(stream: TextIO = sys.stderr, env: Mapping[str, str] = os.environ) -> bool:
    value = env.get("JOURNAL_STREAM", "")
    try:
        device, inode = (int(part) for part in value.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):  # unset, malformed, or a stream without a file
        return False
    return (st.st_dev, st.st_ino) == (device, inode)


class JournalFormatter(logging.Formatter):
    """The prefix on every line: a traceback's lines are separate journal entries."""

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{sd_priority(record.levelno)}>"
        return "\n".join(prefix + line for line in super().format(record).split("\n"))


def configure_logging(stream: TextIO = sys.stderr, level: int = logging.INFO) -> bool:
    """Root logging to `stream`, sd-daemon prefixed when it is the journal; returns which."""
    journal = stream_is_journal(stream)
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JournalFormatter(PLAIN_FORMAT) if journal else logging.Formatter(PLAIN_FORMAT))
    logging.basicConfig(level=level, handlers=[handler], force=True)
    return journal


def error_prefix(stream: TextIO = sys.stderr) -> str:
    """What goes before a line printed to `stream` that is an error ("" off the journal)."""
    return f"<{sd_priority(logging.ERROR)}>" if stream_is_journal(stream) else ""
