"""Rate-limited logging of what remote peers do wrong.

A peer decides how often it sends a bad frame or a refused write; if each one logged a
line, a hostile or broken client would decide how fast the journal fills (seen: a bad
protocol-id frame logged 4–20× its own bytes). Here each (peer, kind) logs its first
event at once, then at most one line per interval carrying the count of what happened
meanwhile ("… (37 more since the last line)"). The table of peers is bounded: when it is
full, new peers share one "other peers" entry.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

#: Peers tracked one by one; beyond, they are counted together (bounded memory).
MAX_TRACKED_PEERS = 256
OTHER_PEERS = "other peers"


@dataclass
class _Entry:
    last_logged_s: float
    suppressed: int = 0
    last_message: str = ""
    level: int = logging.WARNING


class PeerLogLimiter:
    """`note(peer, kind, message)` logs at most once per `interval_s` per (peer, kind)."""

    def __init__(
        self,
        logger: logging.Logger,
        interval_s: float = 10.0,
        level: int = logging.WARNING,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not interval_s > 0:
            raise ValueError(f"interval_s {interval_s!r} must be > 0")
        self._log = logger
        self.interval_s = interval_s
        self._level = level
        self._clock = clock
        self._entries: dict[tuple[str, str], _Entry] = {}
        #: Lines actually written (tests and the benchmark compare it with the events).
        self.lines = 0

    def note(self, peer: str, kind: str, message: str, level: int | None = None) -> None:
        """One event: `message` is the line's text (without the peer), `kind` groups
        events that share a limit (e.g. "bad frame", "refused write"); `level`: the
        limiter's unless given (the first one given for a kind stays its level)."""
        now = self._clock()
        key = (peer, kind)
        entry = self._entries.get(key)
        if entry is None:
            if len(self._entries) >= MAX_TRACKED_PEERS:
                key = (OTHER_PEERS, kind)
                entry = self._entries.get(key)
            if entry is None:
                self._entries[key] = entry = _Entry(last_logged_s=now, level=self._level if level is None else level)
                self._emit(key, entry, message)
                return
        if now - entry.last_logged_s >= self.interval_s:
            self._emit(key, entry, message, self._more(entry.suppressed))
            entry.last_logged_s = now
            entry.suppressed = 0
        else:
            entry.suppressed += 1
            entry.last_message = message

    def flush(self, everything: bool = False) -> None:
        """Log the counts held back for longer than the interval, and forget quiet peers
        (call it now and then, e.g. from a housekeeping timer); `everything`: every count
        held back, whatever its age (at a stop)."""
        now = self._clock()
        for key, entry in list(self._entries.items()):
            if now - entry.last_logged_s < self.interval_s and not (everything and entry.suppressed):
                continue
            if entry.suppressed:
                self._emit(key, entry, entry.last_message, f" ({entry.suppressed} times since the last line)")
                entry.last_logged_s = now
                entry.suppressed = 0
            else:
                del self._entries[key]

    def _more(self, suppressed: int) -> str:
        return f" ({suppressed} more since the last line)" if suppressed else ""

    def _emit(self, key: tuple[str, str], entry: _Entry, message: str, suffix: str = "") -> None:
        self._log.log(entry.level, "%s: %s%s", key[0], message, suffix)
        self.lines += 1
