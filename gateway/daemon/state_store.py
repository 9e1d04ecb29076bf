"""State that must survive a restart (tare offset, bias, last position), persisted atomically.

Write to a temporary file in the same directory, fsync, rename over the old one, fsync
the directory: after a crash the file is either the old or the new state, never half.

The file is untrusted input when read back (a user, a backup tool or a bad disk may
have written it): every field is checked for type, finiteness and range, and a file
that fails any check is moved aside (``state.json.bad-<UTC time>``) with one warning
and the gateway starts unreferenced from defaults — never a crash, never a NaN
published. A temporary file left by a kill during a save is removed at load.
"""
from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import stat
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

log = logging.getLogger(__name__)

STATE_VERSION = 1
#: A state file is a few hundred bytes; anything much larger is not ours.
MAX_STATE_BYTES = 64 * 1024
#: No linear axis this gateway serves is 10 km long: beyond, the number is garbage.
MAX_ABS_POSITION_M = 1.0e4
#: The ADXL202 measures ±2 g; a bias beyond that cannot be a bias of this sensor.
MAX_ABS_BIAS_MPS2 = 2 * 9.80665
#: Bad files kept beside the state file for a post-mortem; older ones are deleted.
KEEP_BAD_FILES = 3


@dataclass
class PersistentState:
    tare_offset_m: float = 0.0
    # the board's last known bias estimate, m/s²: a warm start, never trusted as a reference
    bias_estimate_mps2: float | None = None
    # the last published position: after a restart the gateway starts from it, flagged
    # NOT_REFERENCED (the axis may have moved while the gateway was down)
    last_position_m: float | None = None
    saved_at_unix_s: float | None = None
    # set only by an orderly stop while the axis stood (a trusted standstill): then, and on
    # a first start with no state at all, `estimator.start_at_rest` may be believed. A save
    # while running leaves it out, so after a crash, kill -9 or watchdog abort the next
    # start does not take a cruise for a rest (docs/daemon.md, Faults, scored)
    stopped_at_rest_unix_s: float | None = None


#: field -> (may be None, largest magnitude allowed)
_LIMITS: dict[str, tuple[bool, float]] = {
    "tare_offset_m": (False, MAX_ABS_POSITION_M),
    "bias_estimate_mps2": (True, MAX_ABS_BIAS_MPS2),
    "last_position_m": (True, MAX_ABS_POSITION_M),
    "saved_at_unix_s": (True, 1.0e11),  # year ~5000; negative times are refused below
    "stopped_at_rest_unix_s": (True, 1.0e11),
}


class StateFileError(ValueError):
    """The state file's content is not a state this version wrote (the message says why)."""


def _reject_constant(name: str) -> float:
    # json accepts NaN, Infinity and -Infinity by default; a state never holds them
    raise StateFileError(f"non-finite number {name}")


def parse_state(text: str) -> PersistentState:
    """The state in `text` (a state file's content), or StateFileError naming the fault."""
    try:
        data = json.loads(text, parse_constant=_reject_constant)
    except RecursionError as err:  # "[[[[…" nested thousands deep
        raise StateFileError("JSON nested too deep") from err
    except json.JSONDecodeError as err:
        raise StateFileError(f"not JSON: {err}") from err
    if not isinstance(data, dict):
        raise StateFileError(f"expected a JSON object, got {type(data).__name__}")
    version = data.get("version")
    if type(version) is not int or version != STATE_VERSION:
        raise StateFileError(f"state version {version!r}, expected {STATE_VERSION}")
    known = {f.name for f in fields(PersistentState)}
    unknown = sorted(set(data) - known - {"version"})
    if unknown:
        raise StateFileError(f"unknown field {unknown[0]!r}")
    values: dict[str, float | None] = {}
    for name in known:
        if name not in data:
            continue
        values[name] = _checked_number(name, data[name])
    return PersistentState(**values)


def _checked_number(name: str, value: object) -> float | None:
    may_be_none, limit = _LIMITS[name]
    if value is None and may_be_none:
        return None
    # bool is an int in Python and a string is not a number: both refused by name
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StateFileError(f"{name} = {value!r:.40} is not a number")
    if isinstance(value, int) and abs(value) > limit:  # before float(): 10**400 overflows it
        raise StateFileError(f"{name} = {value!r:.40} outside ±{limit:g}")
    number = float(value)
    if not math.isfinite(number):
        raise StateFileError(f"{name} = {value!r:.40} is not finite")
    if abs(number) > limit or (name.endswith("_unix_s") and number < 0):
        raise StateFileError(f"{name} = {number:g} outside ±{limit:g}")
    return number


def check_travel(state: PersistentState, travel_m: tuple[float, float]) -> None:
    """StateFileError if the saved position lies outside the axis's travel: not a place the
    axis can be, so the file is not this axis's (a restored state, a copy, a hand edit)."""
    lo, hi = travel_m
    pos = state.last_position_m
    if pos is not None and not lo <= pos <= hi:
        raise StateFileError(f"last_position_m = {pos:g} outside the axis's travel "
                             f"[{lo:g}, {hi:g}] m (estimator.travel_m)")


def restored_position_std_m(state: PersistentState, now_unix_s: float, top_speed_mps: float,
                            travel_m: tuple[float, float], still_while_down: bool) -> float:
    """How uncertain a restored position is: what the axis could have done unwatched.

    The position was last known when the state was saved. Since then the axis may have
    moved at up to the machine's top speed — unless the run stopped in order at rest and
    the config says nothing moves the axis while the gateway is down (0 then). Never more
    than the travel's span: the axis cannot leave it. No position saved (a run killed before
    its first save, a file refused): anywhere in the travel. A save time in the future (a clock
    set back) or none tells nothing of the time unwatched: the travel's span.
    """
    span_m = travel_m[1] - travel_m[0]
    if state.last_position_m is None:
        return span_m  # a run before this one, but no position kept (or a bad file): anywhere
    if still_while_down and state.stopped_at_rest_unix_s is not None:
        return 0.0
    saved = state.saved_at_unix_s
    if saved is None or saved > now_unix_s:
        return span_m
    return min(span_m, top_speed_mps * (now_unix_s - saved))


class StateStore:
    def __init__(self, path: str | os.PathLike, travel_m: tuple[float, float] | None = None):
        self.path = Path(path)
        #: a saved position outside it is refused (check_travel); None: not checked
        self.travel_m = travel_m
        self.last_error: str | None = None
        #: Where the last bad file was moved (None if none was, or it could not be moved).
        self.moved_aside: Path | None = None
        #: The last load found no state file at all (a first start), as opposed to a
        #: file, good or bad: what the gateway may assume of the axis depends on it.
        self.found_none = False

    @property
    def temp_path(self) -> Path:
        return self.path.with_name(f".{self.path.name}.tmp")

    def load(self) -> PersistentState:
        """The saved state, or defaults when there is none or it is bad.

        A bad file is moved aside with one warning (the reason and the new name);
        a temporary file left by an interrupted save is deleted first.
        """
        self._remove_stale_temp()
        self.found_none = False
        try:
            raw = _read_regular_file(self.path, MAX_STATE_BYTES + 1)
        except FileNotFoundError:
            self.found_none = True
            return PersistentState()
        except OSError as err:  # a directory, no permission, I/O error: not a bad file, leave it
            self.last_error = f"{self.path}: unreadable state, starting unreferenced: {err.strerror or err}"
            log.warning("%s", self.last_error)
            return PersistentState()
        try:
            if len(raw) > MAX_STATE_BYTES:
                raise StateFileError(f"larger than {MAX_STATE_BYTES} bytes")
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as err:
                raise StateFileError(f"not UTF-8 at byte {err.start}") from err
            state = parse_state(text)
            if self.travel_m is not None:
                check_travel(state, self.travel_m)
            return state
        except StateFileError as err:
            self.moved_aside = self._move_aside()
            where = f"moved to {self.moved_aside.name}" if self.moved_aside else "could not be moved aside"
            self.last_error = f"{self.path}: unreadable state, starting unreferenced ({where}): {err}"
            log.warning("%s", self.last_error)
            return PersistentState()

    def save(self, state: PersistentState) -> bool:
        data = {"version": STATE_VERSION, **asdict(state)}
        tmp = self.temp_path
        try:
            # allow_nan=False: a NaN that slipped through must fail here, not be written
            text = json.dumps(data, indent=1, allow_nan=False)
        except ValueError:
            self.last_error = f"{self.path}: not saving a state with a non-finite number: {data}"
            log.error("%s", self.last_error)
            return False
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
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
            self._remove_stale_temp()
            return False

    # ------------------------------------------------------------ internals --
    def _remove_stale_temp(self) -> None:
        try:
            self.temp_path.unlink()
            log.info("%s: removed a temporary file left by an interrupted save", self.temp_path)
        except FileNotFoundError:
            pass
        except OSError as err:
            log.warning("%s: cannot remove: %s", self.temp_path, err.strerror or err)

    def _move_aside(self) -> Path | None:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        target = self.path.with_name(f"{self.path.name}.bad-{stamp}")
        try:
            os.replace(self.path, target)
        except OSError as err:
            log.warning("%s: cannot move the bad state file aside: %s", self.path, err.strerror or err)
            return None
        old = sorted(self.path.parent.glob(f"{self.path.name}.bad-*"))[:-KEEP_BAD_FILES]
        for path in old:
            with contextlib.suppress(OSError):  # keeping one too many is harmless
                path.unlink()
        return target


def _read_regular_file(path: Path, limit: int) -> bytes:
    """At most `limit` bytes of a regular file; OSError for anything else.

    Opened non-blocking and checked before reading: a FIFO at the path would block open()
    and read() until a writer came (the daemon would never listen), a device could hand
    out bytes without end."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise OSError(0, "not a regular file")
        with os.fdopen(fd, "rb", closefd=False) as fh:
            return fh.read(limit)
    finally:
        os.close(fd)
