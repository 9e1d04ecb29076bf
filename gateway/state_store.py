"""State that must survive a restart (tare offset, calibration), persisted atomically.

Write to a temporary file in the same directory, fsync, rename over the old one, fsync
the directory: after a crash the file is either the old or the new state, never half.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

STATE_VERSION = 1


@dataclass
class PersistentState:
    tare_offset_m: float = 0.0
    # the board's last known bias estimate, m/s²: a warm start, never trusted as a reference
    bias_estimate_mps2: float | None = None
    # the last published position: after a restart the gateway starts from it, flagged
    # NOT_REFERENCED (the axis may have moved while the gateway was down)
    last_position_m: float | None = None
    saved_at_unix_s: float | None = None


class StateStore:
    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.last_error: str | None = None

    def load(self) -> PersistentState:
        """The saved state, or defaults (with the reason logged) when there is none or it is unreadable."""
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            if data.get("version") != STATE_VERSION:
                raise ValueError(f"state version {data.get('version')!r}, expected {STATE_VERSION}")
            known = {k: data[k] for k in PersistentState.__dataclass_fields__ if k in data}
            state = PersistentState(**known)
            if not isinstance(state.tare_offset_m, (int, float)):
                raise ValueError("tare_offset_m is not a number")
            return state
        except FileNotFoundError:
            return PersistentState()
        except (OSError, ValueError, TypeError, AttributeError) as err:
            self.last_error = f"{self.path}: unreadable state, starting unreferenced: {err}"
            log.warning("%s", self.last_error)
            return PersistentState()

    def save(self, state: PersistentState) -> bool:
        data = {"version": STATE_VERSION, **asdict(state)}
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w", encoding="utf-8") as fh:
                json.dump(data, fh, indent=1)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            dir_fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(dir_fd)
            finally:
                os.close(dir_fd)
            self.last_error = None
            return True
        except OSError as err:
            self.last_error = f"{self.path}: cannot save state: {err.strerror or err}"
            log.error("%s", self.last_error)
            return False
