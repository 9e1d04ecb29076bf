"""What the gateway puts on the wires: one snapshot per publish cycle, never changed
after it is built.

The daemon builds a `PublishedValues` from the estimator and the board driver and
hands it to every publisher (`ModbusServer.update`, `CanPublisher.update`). The
publishers only encode it; they never invent values. Units are SI and in the names.

Missing numbers are NaN (floats) or None where stated; each publisher documents how it
encodes them (NaN in float32 registers, a sentinel in scaled integers).
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass


class StatusBits(enum.IntFlag):
    """Quality and state of the published values, one bit each (16 bits on the wire).

    The bit positions are part of the Modbus map and the DBC file: never renumber,
    only add. A PLC should gate every use of position/velocity on VALID.
    """

    #: Position, velocity and acceleration are live, trustworthy estimates: the board
    #: delivers fresh samples and the estimator is healthy. Clear whenever any of
    #: STALE, BOARD_LOST, ESTIMATOR_FAULT, HOLDING or AXIS_INVALID is set.
    VALID = 1 << 0
    #: The estimator detects standstill (velocity held at zero, bias may be learnt).
    STANDSTILL = 1 << 1
    #: The newest sample is older than the configured stale limit (samples late or
    #: missing for a short time); the numbers are the last ones computed.
    STALE = 1 << 2
    #: No frames from the board for longer than the board timeout, or the serial port
    #: is gone. The daemon keeps reconnecting; values are not live.
    BOARD_LOST = 1 << 3
    #: The sensor reading is at the ADXL202 range limit (about ±2 g) or the board
    #: flagged a capture timeout/overflow: acceleration is clipped, position suspect.
    SATURATED = 1 << 4
    #: No tare since the daemon started (or since a board reset): position counts from
    #: wherever the axis stood at start-up, not from a reference.
    NOT_REFERENCED = 1 << 5
    #: The estimator failed a consistency check (diverging covariance, innovation far
    #: outside its expected size) and was re-initialised; values are not trustworthy.
    ESTIMATOR_FAULT = 1 << 6
    #: Outputs are frozen at their last value on purpose (e.g. while the estimator
    #: re-initialises or the bias is being re-estimated); they are not live.
    HOLDING = 1 << 7
    #: The configured axis cannot be computed (calibration missing or invalid, axis
    #: capture flagged on every sample).
    AXIS_INVALID = 1 << 8
    #: The configuration was reloaded recently (the daemon sets this for a while after
    #: a reload so a PLC can notice a change of scaling or limits).
    CONFIG_RELOADED = 1 << 9
    #: The board reset recently (HELLO seen): continuity was lost, counters restarted.
    BOARD_RESET = 1 << 10
    #: Samples were lost on the serial line recently (sequence gap).
    SAMPLES_LOST = 1 << 11
    #: A bias re-estimation is in progress (commanded or automatic).
    BIAS_ESTIMATING = 1 << 12
    #: Set by a publisher, never by the daemon: at least one scaled integer on this
    #: wire (int32 µm, µm/s, µm/s²; CAN int16) was clamped at its range limit. The
    #: float32 registers carry the unclamped value.
    SCALED_CLAMPED = 1 << 13
    #: The position is not trustworthy now: the accelerometer cannot tell whether the
    #: axis cruises or stands (a long quiet stretch the velocity test cannot decide,
    #: after a gap, a restart or a board reset mid-move, a possible offset step). Held
    #: until a stop is accepted on evidence (a decisive velocity test, the machine's rest
    #: hint, or a quiet stretch longer than any cruise within estimator.travel_m). VALID is clear.
    POSITION_UNTRUSTED = 1 << 14
    #: Set by the Modbus server, never by the daemon, and only in the Modbus registers:
    #: Modbus RTU is configured but its serial port is missing or lost; the server keeps
    #: reopening it with back-off.
    MODBUS_RTU_DOWN = 1 << 15


class StatusExtBits(enum.IntFlag):
    """The second status word (Modbus STATUS_EXT, CAN ADXL_Quality Qual_StatusExt): what
    the first has no room for. Never renumber, only add."""

    #: The board is the built-in emulated one (`port = "emulated"`, `adxlgw demo`): the
    #: numbers are a simulation's, not a machine's.
    SIMULATED = 1 << 0
    #: The machine's hint in force: "axis at rest" / "axis moving" (none: unknown or expired).
    HINT_AT_REST = 1 << 1
    HINT_MOVING = 1 << 2
    #: "At rest" is hinted but a whole window of the accelerometer shows motion: the hint
    #: is not obeyed (check the PLC's in-position signal or the sensor's mounting).
    HINT_CONFLICT = 1 << 3
    #: A quiet stretch after a move sits off the bias: the sensor's offset may have stepped.
    OFFSET_STEP = 1 << 4
    #: The current standstill was accepted on the machine's hint.
    STOP_BY_HINT = 1 << 5
    #: The MQTT (Sparkplug B) edge node is on but not publishing: not connected to its
    #: broker (it keeps reconnecting), or waiting for its primary host to be online; the
    #: fleet's host sees this gateway as dead meanwhile.
    MQTT_DOWN = 1 << 6


#: Bits that say "do not use the numbers"; VALID must be clear when any is set.
NOT_USABLE_BITS = (
    StatusBits.STALE
    | StatusBits.BOARD_LOST
    | StatusBits.ESTIMATOR_FAULT
    | StatusBits.HOLDING
    | StatusBits.AXIS_INVALID
    | StatusBits.POSITION_UNTRUSTED
)


class Command(enum.IntEnum):
    """Commands a PLC can send; the values are the CAN command codes too."""

    #: Set the position to zero here (position := 0) and clear NOT_REFERENCED.
    TARE = 1
    #: Re-estimate the accelerometer bias; the daemon accepts it only at standstill.
    REESTIMATE_BIAS = 2
    #: The machine's word on the axis (the PLC's "in position"): evidence for the
    #: standstill detector, in force until another hint or estimator.hint_timeout_ms.
    HINT_AT_REST = 3
    HINT_MOVING = 4
    HINT_UNKNOWN = 5


#: Signature of the daemon's command callback. `source` names the wire and peer, e.g.
#: "modbus-tcp:192.168.0.7:50312" or "can:can0". Return True when the command was
#: carried out, False when the daemon declined it (e.g. not at standstill). It is
#: called in the event loop thread and must return quickly (no blocking I/O).
CommandCallback = Callable[[Command, str], bool]


# Not frozen, though no one changes a snapshot once built: the daemon builds one per
# publish a wire reads (20 a second for the MQTT node alone), on a VM cold each time, and
# a frozen dataclass's __init__ sets each of the 17 fields through object.__setattr__:
# 6.2 µs hot against 1.2 µs for plain slots (docs/decisions/0153).
@dataclass(slots=True)
class PublishedValues:
    """One snapshot of everything the Modbus registers, CAN frames and MQTT metrics carry
    (read only: every wire shares the same one)."""

    position_m: float = math.nan
    velocity_mps: float = math.nan
    acceleration_mps2: float = math.nan
    status: StatusBits = StatusBits.BOARD_LOST | StatusBits.NOT_REFERENCED
    #: Incremented by the daemon once per publish cycle; a PLC sees it change as long
    #: as the daemon's loop runs (wraps at 16 bits on the wire).
    heartbeat: int = 0
    #: Number of board samples processed since start (wraps at 32 bits on the wire).
    sample_counter: int = 0
    #: Age of the newest sample when these values were built; None = no sample yet.
    last_sample_age_ms: float | None = None
    #: The estimator's current accelerometer bias (what it subtracts).
    bias_estimate_mps2: float = math.nan
    #: 1-sigma uncertainty of the position estimate.
    position_std_m: float = math.nan
    #: Board temperature; None when the board has no sensor (or no STATUS yet).
    board_temp_c: float | None = None
    #: Samples missing on the serial line (sequence gaps), since start.
    lost_samples: int = 0
    #: Board frames dropped for a CRC mismatch, since start.
    crc_errors: int = 0
    #: Board resets seen (HELLO frames after the first), since start.
    board_resets: int = 0
    #: CAN sends that failed (copied by the daemon from CanPublisher.counters), so a
    #: Modbus client can see the health of the CAN side.
    can_send_errors: int = 0
    #: CAN command frames refused (disabled, E2E: CRC, a counter not ahead — a replay —,
    #: length, code), copied from CanPublisher.counters.commands_rejected.
    can_refused_commands: int = 0
    #: The second status word (StatusExtBits).
    status_ext: StatusExtBits = StatusExtBits(0)
    #: DDATA the MQTT edge node dropped since start (its queue was full), copied by the
    #: daemon like can_send_errors.
    mqtt_dropped: int = 0

    @property
    def usable(self) -> bool:
        """True when a consumer may act on position/velocity (VALID and nothing against)."""
        return usable_status(self.status)


_VALID = int(StatusBits.VALID)
_NOT_USABLE = int(NOT_USABLE_BITS)


def usable_status(status: int) -> bool:
    """`PublishedValues.usable` of a status word: in plain ints, as the MQTT node reads it
    for every DDATA (a flag operation on StatusBits is a Python call)."""
    return status & _VALID != 0 and status & _NOT_USABLE == 0


#: What publishers serve before the daemon's first update: nothing measured yet.
NOTHING_PUBLISHED = PublishedValues()

#: What a publisher's `update()` takes: a snapshot, or a function that returns the
#: newest snapshot, which the publisher calls only when it needs the values (a Modbus
#: read, a CAN transmission) — the daemon updates once per board sample, 500 times a
#: second, while clients read and frames go out far less often.
ValuesSource = PublishedValues | Callable[[], PublishedValues]


def current(values: ValuesSource) -> PublishedValues:
    """The snapshot a `ValuesSource` stands for."""
    return values if isinstance(values, PublishedValues) else values()


@functools.cache
def flag_word(kind: type[enum.IntFlag], bits: int) -> enum.IntFlag:
    """kind(bits), made once per value: an IntFlag built from an int is two Python calls
    (enum's __call__ and __new__), and the daemon builds its status words per snapshot;
    the words a gateway shows are few (at most 2**16 per kind)."""
    return kind(bits)
