"""CAN frames of the gateway: one table, the E2E protection, packing.

`FRAMES` is the single source. The publisher packs and unpacks with it,
`dbc_text()` (drivers/can_frames_text.py, with the Markdown tables of the docs)
generates the DBC from it, and config/adxl-gateway.dbc is that text
committed for users (a test fails if they differ). Nothing about the layout is written
twice. The identifiers are configurable (`can.base_id`, so that two gateways can share a
bus): `frame_table(base_id)` is the same table moved to other identifiers, and every
function here takes the table it works on (the default one unless told).

Layout rules (details and rationale in docs/can-frames.md):
- Classic CAN, 11-bit identifiers, DLC 8, all signals little-endian (Intel).
- Every frame is protected like AUTOSAR E2E profile 1 (variant 1A, data ID mode BOTH):
  byte 0 is a CRC-8, the low nibble of byte 1 an alive counter 0..14 (15 is never
  sent and is invalid), and the CRC covers the data ID (low byte, then high byte)
  followed by bytes 1..7. The CRC is CRC-8/SAE-J1850's polynomial 0x1D; profile 1
  calls the library with start value 0xFF as a continuation and XORs 0xFF at the end,
  which comes to: initial value 0x00, no reflection, no final XOR (CRC-8/GSM-A
  parameters). The data ID of each frame is its CAN identifier.
- Scaled integers that have no valid value carry the most negative raw value
  (int32 0x80000000, int16 0x8000); out-of-range values clamp to ±(2^(n-1) − 1) and set
  SCALED_CLAMPED in the status word.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

from .published_values import Command, PublishedValues, StatusBits

GATEWAY_NODE = "ADXL_GW"
PLC_NODE = "PLC"

COUNTER_MAX = 14  # E2E profile 1: the alive counter runs 0..14, 15 is invalid
CRC8_POLY = 0x1D


# --------------------------------------------------------------------------- #
# The table
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, slots=True)
class SignalSpec:
    name: str
    #: Intel (little-endian) start bit = position of the least significant bit.
    start_bit: int
    length: int
    signed: bool
    factor: float
    minimum: float
    maximum: float
    unit: str
    comment: str
    choices: tuple[tuple[int, str], ...] = ()

    def raw_limits(self) -> tuple[int, int]:
        if self.signed:
            return -(2 ** (self.length - 1)), 2 ** (self.length - 1) - 1
        return 0, 2**self.length - 1


@dataclass(frozen=True, slots=True)
class FrameSpec:
    name: str
    frame_id: int
    sender: str
    receiver: str
    #: None = sent on event (command and its acknowledgement).
    cycle_time_ms: int | None
    comment: str
    signals: tuple[SignalSpec, ...]
    dlc: int = 8

    @property
    def data_id(self) -> int:
        """E2E data ID mixed into the CRC (catches a frame on the wrong identifier)."""
        return self.frame_id

    def signal(self, suffix: str) -> SignalSpec:
        """The signal named '<prefix>_<suffix>' (each frame prefixes its own names)."""
        for spec in self.signals:
            if spec.name.split("_", 1)[1] == suffix:
                return spec
        raise KeyError(f"{self.name} has no signal *_{suffix}")


def _e2e_header(prefix: str, flags: bool) -> tuple[SignalSpec, ...]:
    header = (
        SignalSpec(f"{prefix}_CRC", 0, 8, False, 1, 0, 255, "",
                   "E2E profile 1 CRC-8 over data ID and bytes 1..7."),
        SignalSpec(f"{prefix}_Counter", 8, 4, False, 1, 0, COUNTER_MAX, "",
                   "E2E alive counter, +1 per frame sent, 0..14 then 0 again."),
    )
    if not flags:
        return header
    # The four bits a receiver needs to judge the numbers travel in every cyclic frame.
    return header + (
        SignalSpec(f"{prefix}_Valid", 12, 1, False, 1, 0, 1, "", "StatusBits.VALID."),
        SignalSpec(f"{prefix}_Standstill", 13, 1, False, 1, 0, 1, "", "StatusBits.STANDSTILL."),
        SignalSpec(f"{prefix}_Stale", 14, 1, False, 1, 0, 1, "", "StatusBits.STALE."),
        SignalSpec(f"{prefix}_BoardLost", 15, 1, False, 1, 0, 1, "", "StatusBits.BOARD_LOST."),
    )


class AckResult(enum.IntEnum):
    """What the gateway did with a command frame (signal Ack_Result)."""

    DONE = 0
    DECLINED = 1  # the daemon declined (e.g. not at standstill)
    FAILED = 2  # the daemon's handler raised
    DISABLED = 3  # commands over CAN are not enabled
    CRC_ERROR = 4
    COUNTER_ERROR = 5  # counter 15, or not 1..MAX_COUNTER_DELTA ahead of the previous command (a replay)
    UNKNOWN_COMMAND = 6
    BAD_LENGTH = 7


_INT32_NA = -(2**31)
_INT16_NA = -(2**15)

# fmt: off
POSITION_FRAME = FrameSpec(
    "ADXL_Position", 0x120, GATEWAY_NODE, PLC_NODE, 10,
    "Position and full status word, cyclic.",
    _e2e_header("Pos", flags=True) + (
        SignalSpec("Pos_Position", 16, 32, True, 0.000001, -2147.483647, 2147.483647, "m",
                   "Position, 1 um per bit; raw -2147483648 = not available.",
                   ((_INT32_NA, "NotAvailable"),)),
        SignalSpec("Pos_Status", 48, 16, False, 1, 0, 65535, "",
                   "StatusBits word, same bits as Modbus input register STATUS."),
    ),
)
VELOCITY_FRAME = FrameSpec(
    "ADXL_Velocity", 0x121, GATEWAY_NODE, PLC_NODE, 10,
    "Velocity and acceleration, cyclic.",
    _e2e_header("Vel", flags=True) + (
        SignalSpec("Vel_Velocity", 16, 32, True, 0.000001, -2147.483647, 2147.483647, "m/s",
                   "Velocity, 1 um/s per bit; raw -2147483648 = not available.",
                   ((_INT32_NA, "NotAvailable"),)),
        SignalSpec("Vel_Acceleration", 48, 16, True, 0.001, -32.767, 32.767, "m/s2",
                   "Acceleration, 1 mm/s2 per bit (ADXL202 range is about 19.6 m/s2); "
                   "raw -32768 = not available.",
                   ((_INT16_NA, "NotAvailable"),)),
    ),
)
_UINT32_NA = 2**32 - 1
QUALITY_FRAME = FrameSpec(
    "ADXL_Quality", 0x122, GATEWAY_NODE, PLC_NODE, 10,
    "How far to trust the numbers: the position's standard deviation and the second status word, cyclic.",
    _e2e_header("Qual", flags=True) + (
        SignalSpec("Qual_PositionStd", 16, 32, False, 0.000001, 0, 4294.967294, "m",
                   "1-sigma uncertainty of the position, 1 um per bit (saturates at the top); raw "
                   "4294967295 = not available.", ((_UINT32_NA, "NotAvailable"),)),
        SignalSpec("Qual_StatusExt", 48, 16, False, 1, 0, 65535, "",
                   "StatusExtBits word, same bits as Modbus input register STATUS_EXT: 0 SIMULATED, "
                   "1 HINT_AT_REST, 2 HINT_MOVING, 3 HINT_CONFLICT, 4 OFFSET_STEP, 5 STOP_BY_HINT."),
    ),
)
COMMAND_FRAME = FrameSpec(
    "ADXL_Command", 0x130, PLC_NODE, GATEWAY_NODE, None,
    "Command to the gateway; executed only when commands are enabled and the E2E check passes.",
    _e2e_header("Cmd", flags=False) + (
        SignalSpec("Cmd_Code", 16, 8, False, 1, 0, 255, "",
                   "Command code.", tuple((int(c), c.name) for c in Command)),
    ),
)
ACK_FRAME = FrameSpec(
    "ADXL_CommandAck", 0x131, GATEWAY_NODE, PLC_NODE, None,
    "Answer to every ADXL_Command frame received.",
    _e2e_header("Ack", flags=False) + (
        SignalSpec("Ack_Code", 16, 8, False, 1, 0, 255, "",
                   "Command code of the frame answered.", tuple((int(c), c.name) for c in Command)),
        SignalSpec("Ack_CommandCounter", 24, 4, False, 1, 0, 15, "",
                   "Alive counter of the command frame answered."),
        SignalSpec("Ack_Result", 32, 8, False, 1, 0, 255, "",
                   "What the gateway did.", tuple((int(r), r.name) for r in AckResult)),
    ),
)
# fmt: on

DEFAULT_BASE_ID = POSITION_FRAME.frame_id
# where each frame sits above the base identifier
_OFFSETS = {"position": 0x00, "velocity": 0x01, "quality": 0x02, "command": 0x10, "ack": 0x11}
MAX_BASE_ID = 0x7FF - max(_OFFSETS.values())  # 11-bit identifiers


@dataclass(frozen=True, slots=True)
class FrameTable:
    """The four frames on one gateway's identifiers."""

    position: FrameSpec
    velocity: FrameSpec
    quality: FrameSpec
    command: FrameSpec
    ack: FrameSpec

    @property
    def frames(self) -> tuple[FrameSpec, ...]:
        return (self.position, self.velocity, self.quality, self.command, self.ack)

    @property
    def cyclic(self) -> tuple[FrameSpec, ...]:
        return (self.position, self.velocity, self.quality)

    @property
    def base_id(self) -> int:
        return self.position.frame_id


def frame_table(base_id: int = DEFAULT_BASE_ID) -> FrameTable:
    """The frames at base_id (position), +1 (velocity), +2 (quality), +0x10 (command), +0x11 (ack); the
    E2E data ID of each follows its identifier, so a frame read under another gateway's
    identifier fails its CRC."""
    if not 0 <= base_id <= MAX_BASE_ID:
        raise ValueError(f"CAN base identifier must be 0..0x{MAX_BASE_ID:03X}, got 0x{base_id:X}")
    frames = {name: replace(spec, frame_id=base_id + _OFFSETS[name]) for name, spec in
              (("position", POSITION_FRAME), ("velocity", VELOCITY_FRAME), ("quality", QUALITY_FRAME),
               ("command", COMMAND_FRAME), ("ack", ACK_FRAME))}
    return FrameTable(**frames)


DEFAULT_FRAMES = frame_table()
FRAMES: tuple[FrameSpec, ...] = DEFAULT_FRAMES.frames


# --------------------------------------------------------------------------- #
# CRC and E2E profile 1
# --------------------------------------------------------------------------- #
def _crc8_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


CRC8_TABLE = _crc8_table(CRC8_POLY)


def crc8(data: bytes, init: int = 0xFF, xor_out: int = 0xFF) -> int:
    """CRC-8 with polynomial 0x1D, MSB first. Defaults are CRC-8/SAE-J1850 (check 0x4B)."""
    crc = init
    for byte in data:
        crc = CRC8_TABLE[crc ^ byte]
    return crc ^ xor_out


def e2e_p01_crc(data_id: int, payload: bytes) -> int:
    """E2E profile 1 CRC of a frame (payload byte 0 is the CRC itself and is skipped)."""
    covered = bytes((data_id & 0xFF, (data_id >> 8) & 0xFF)) + bytes(payload[1:])
    return crc8(covered, init=0x00, xor_out=0x00)


def e2e_p01_protect(frame: FrameSpec, payload: bytearray, counter: int) -> None:
    """Write the counter (low nibble of byte 1) and then the CRC (byte 0) in place."""
    if not 0 <= counter <= COUNTER_MAX:
        raise ValueError(f"E2E counter {counter} outside 0..{COUNTER_MAX}")
    payload[1] = (payload[1] & 0xF0) | counter
    payload[0] = e2e_p01_crc(frame.data_id, payload)


def next_counter(counter: int) -> int:
    return 0 if counter >= COUNTER_MAX else counter + 1


# --------------------------------------------------------------------------- #
# Packing
# --------------------------------------------------------------------------- #
def pack(frame: FrameSpec, raw: Mapping[str, int]) -> bytearray:
    """Payload with the given raw signal values (missing signals are 0)."""
    word = 0
    for spec in frame.signals:
        value = int(raw.get(spec.name, 0))
        low, high = spec.raw_limits()
        if not low <= value <= high:
            raise ValueError(f"{spec.name}: raw {value} outside {low}..{high}")
        word |= (value & ((1 << spec.length) - 1)) << spec.start_bit
    return bytearray(word.to_bytes(frame.dlc, "little"))


def unpack(frame: FrameSpec, payload: bytes) -> dict[str, int]:
    """Raw signal values of a payload of the frame's length."""
    if len(payload) != frame.dlc:
        raise ValueError(f"{frame.name}: {len(payload)} bytes, expected {frame.dlc}")
    word = int.from_bytes(payload, "little")
    raw = {}
    for spec in frame.signals:
        value = (word >> spec.start_bit) & ((1 << spec.length) - 1)
        if spec.signed and value & (1 << (spec.length - 1)):
            value -= 1 << spec.length
        raw[spec.name] = value
    return raw


class CyclicEncoder:
    """The encoder of the two cyclic frames (ADXL_Position, ADXL_Velocity): everything
    that depends only on the frame table is worked out once, since it runs 100 times a
    second per frame pair. The one encoder of these frames (the publisher sends its
    bytes); tests/can/test_can_frames.py checks it against cantools decoding the DBC that
    `dbc_text()` writes from the same table — an independent decoder.

    Scaled signals: value / factor rounded to the nearest raw step; beyond the signed
    range (±inf included) clamped to the largest raw magnitude and SCALED_CLAMPED set in
    the status; NaN (missing) is the most negative raw value, "NotAvailable" in the DBC.
    """

    def __init__(self, table: FrameTable = DEFAULT_FRAMES) -> None:
        self.table = table
        pos_frame, vel_frame, qual_frame = table.position, table.velocity, table.quality
        self._pos_id, self._vel_id, self._qual_id = pos_frame.frame_id, vel_frame.frame_id, qual_frame.frame_id
        std, ext = qual_frame.signal("PositionStd"), qual_frame.signal("StatusExt")
        self._std = (std.factor, std.start_bit, (1 << std.length) - 1)
        self._ext_shift, self._ext_mask = ext.start_bit, (1 << ext.length) - 1
        pos = pos_frame.signal("Position")
        status = pos_frame.signal("Status")
        vel = vel_frame.signal("Velocity")
        acc = vel_frame.signal("Acceleration")
        # (factor, lowest raw, highest raw, start bit, mask) of each scaled signal
        self._pos = (pos.factor, *pos.raw_limits(), pos.start_bit, (1 << pos.length) - 1)
        self._vel = (vel.factor, *vel.raw_limits(), vel.start_bit, (1 << vel.length) - 1)
        self._acc = (acc.factor, *acc.raw_limits(), acc.start_bit, (1 << acc.length) - 1)
        self._status_shift, self._status_mask = status.start_bit, (1 << status.length) - 1
        self._clamped = int(StatusBits.SCALED_CLAMPED)
        # the four status bits each cyclic frame repeats (byte 1, bits 4-7): status bit → frame bit
        self._flags = tuple(
            (int(bit), pos_frame.signal(name).start_bit)
            for name, bit in (("Valid", StatusBits.VALID), ("Standstill", StatusBits.STANDSTILL),
                              ("Stale", StatusBits.STALE), ("BoardLost", StatusBits.BOARD_LOST))
        )
        assert all(f.signal(n).start_bit == pos_frame.signal(n).start_bit for f in (vel_frame, qual_frame)
                   for n in ("Valid", "Standstill", "Stale", "BoardLost"))
        self._counter_shift = pos_frame.signal("Counter").start_bit
        # the CRC register after each frame's data ID (E2E profile 1: initial value 0)
        self._after_id = {
            frame.frame_id: crc8(bytes((frame.data_id & 0xFF, frame.data_id >> 8)), init=0, xor_out=0)
            for frame in (pos_frame, vel_frame, qual_frame)
        }

    def _scaled(self, value: float, spec: tuple) -> tuple[int, bool]:
        """(raw, clamped); NaN is the most negative raw value."""
        factor, low, high = spec[0], spec[1], spec[2]
        if math.isnan(value):
            return low, False
        scaled = value / factor  # ±inf stays ±inf
        if scaled > high:
            return high, True
        if scaled < -high:
            return -high, True
        return round(scaled), False

    def encode(self, values: PublishedValues, pos_counter: int, vel_counter: int,
               qual_counter: int = 0) -> tuple[bytes, bytes, bytes]:
        """Payloads of ADXL_Position, ADXL_Velocity and ADXL_Quality with these alive counters."""
        position, clamped_p = self._scaled(values.position_m, self._pos)
        velocity, clamped_v = self._scaled(values.velocity_mps, self._vel)
        acceleration, clamped_a = self._scaled(values.acceleration_mps2, self._acc)
        status = int(values.status)
        if clamped_p or clamped_v or clamped_a:
            status |= self._clamped
        flags = 0
        for bit, shift in self._flags:
            if status & bit:
                flags |= 1 << shift
        cs = self._counter_shift
        p, v, a = self._pos, self._vel, self._acc
        pos_word = (flags | (pos_counter << cs) | ((position & p[4]) << p[3])
                    | ((status & self._status_mask) << self._status_shift))
        vel_word = flags | (vel_counter << cs) | ((velocity & v[4]) << v[3]) | ((acceleration & a[4]) << a[3])
        factor, std_shift, std_mask = self._std
        std = values.position_std_m
        # an uncertainty has no sign: NaN (unknown) is the n/a value, anything larger saturates below it
        if math.isnan(std):
            std_raw = std_mask
        elif std / factor >= std_mask - 1:  # ±inf included
            std_raw = std_mask - 1
        else:
            std_raw = max(round(std / factor), 0)
        qual_word = (flags | (qual_counter << cs) | (std_raw << std_shift)
                     | ((int(values.status_ext) & self._ext_mask) << self._ext_shift))
        return (self._protect(self._pos_id, pos_word), self._protect(self._vel_id, vel_word),
                self._protect(self._qual_id, qual_word))

    def _protect(self, frame_id: int, word: int) -> bytes:
        payload = bytearray(word.to_bytes(8, "little"))
        table = CRC8_TABLE
        crc = self._after_id[frame_id]
        for byte in payload[1:]:
            crc = table[crc ^ byte]
        payload[0] = crc
        return bytes(payload)


@dataclass(frozen=True, slots=True)
class CommandCheck:
    """Outcome of checking a received command frame."""

    #: None when the frame passed every check; else why not.
    problem: AckResult | None
    command: Command | None
    code: int
    counter: int


#: How far a command's counter may advance over the previous accepted one (E2E profile 1's
#: MaxDeltaCounter): 1 is the next frame, up to 3 tolerates two command frames lost in a row.
#: An older frame (a replay) or the same one again lies behind: refused.
MAX_COUNTER_DELTA = 3


def counter_delta(counter: int, last_counter: int) -> int:
    """How far `counter` is ahead of `last_counter` on the 0..14 ring (0: the same)."""
    return (counter - last_counter) % (COUNTER_MAX + 1)


def check_command(payload: bytes, last_counter: int | None, table: FrameTable = DEFAULT_FRAMES) -> CommandCheck:
    """E2E and content check of an ADXL_Command payload.

    `last_counter` is the counter of the previous accepted command (None: none since the
    gateway started, so any counter 0..14 is accepted); the counter must be ahead of it
    by 1..MAX_COUNTER_DELTA, so a repeat or an older frame replayed is refused
    (COUNTER_ERROR). A sender that restarted re-synchronises with two frames in a row
    (CanPublisher: COMMAND_RESYNC_S).
    """
    frame = table.command
    if len(payload) != frame.dlc:
        code = payload[2] if len(payload) > 2 else 0
        counter = payload[1] & 0x0F if len(payload) > 1 else 0
        return CommandCheck(AckResult.BAD_LENGTH, None, code, counter)
    raw = unpack(frame, payload)
    code, counter = raw["Cmd_Code"], raw["Cmd_Counter"]
    if e2e_p01_crc(frame.data_id, payload) != raw["Cmd_CRC"]:
        return CommandCheck(AckResult.CRC_ERROR, None, code, counter)
    if counter > COUNTER_MAX or (last_counter is not None
                                 and not 1 <= counter_delta(counter, last_counter) <= MAX_COUNTER_DELTA):
        return CommandCheck(AckResult.COUNTER_ERROR, None, code, counter)
    try:
        command = Command(code)
    except ValueError:
        return CommandCheck(AckResult.UNKNOWN_COMMAND, None, code, counter)
    return CommandCheck(None, command, code, counter)


def encode_command(command: Command | int, counter: int, table: FrameTable = DEFAULT_FRAMES) -> bytes:
    """A protected ADXL_Command payload (for PLC-side tools and tests)."""
    payload = pack(table.command, {"Cmd_Code": int(command)})
    e2e_p01_protect(table.command, payload, counter)
    return bytes(payload)


def encode_ack(check: CommandCheck, result: AckResult, counter: int, table: FrameTable = DEFAULT_FRAMES) -> bytes:
    payload = pack(
        table.ack,
        {"Ack_Code": check.code & 0xFF, "Ack_CommandCounter": check.counter & 0x0F, "Ack_Result": int(result)},
    )
    e2e_p01_protect(table.ack, payload, counter)
    return bytes(payload)
