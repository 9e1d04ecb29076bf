"""The Modbus register map: one explicit table and its encoding.

`REGISTERS` is the single source. The server encodes from it, `adxlgw regmap --json`
prints it (drivers/modbus_map_text.py: `regmap_json()`), and docs/modbus-registers.md
embeds `regmap_markdown()` (a test keeps them equal).

Addressing, said once: **addresses in this table and on the wire are 0-based** (the
Modbus PDU carries 0..65535). PLC notation is 1-based and names the table by its first
digit: input register address a is 3xxxx = 30001 + a, holding register address a is
4xxxx = 40001 + a. So `POSITION` at input address 4 is PLC reference 30005, and a
pymodbus client reads it with `read_input_registers(4, count=2)`.

Encoding rules (the why is in docs/modbus-registers.md):
- 32-bit values take two registers; the word order is configurable: ABCD = high word
  first (Modbus's own big-endian order, the default), CDAB = low word first. Bytes
  inside a register are always big-endian.
- float32 with no valid number (NaN, ±inf, beyond float32 range): quiet NaN 0x7FC00000.
- Scaled integers with no valid number: the type's most negative value (int32
  0x80000000, int16 0x8000), which a real value never takes (the SunSpec convention).
  Out-of-range values are clamped to ±(2^(n-1) − 1) and the status bit SCALED_CLAMPED
  is set in the same image.
- Counters wrap modulo 2^n (PLC counter semantics); other unsigned values saturate at
  their maximum; an unknown sample age reads 0xFFFFFFFF.
- Text (string32, the device name): 32 bytes of ASCII in 16 registers, two characters
  per register, the first character in the high byte; padded with NUL bytes.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from .published_values import PublishedValues, StatusBits

#: Bump whenever a row is added, moved or changes meaning; the PLC can check it.
MAP_VERSION = 4

PLC_INPUT_BASE = 30001
PLC_HOLDING_BASE = 40001


class Table(enum.StrEnum):
    INPUT = "input"
    HOLDING = "holding"


class RegType(enum.StrEnum):
    FLOAT32 = "float32"
    INT32 = "int32"
    UINT32 = "uint32"
    UINT16 = "uint16"
    INT16 = "int16"
    BITFIELD = "bitfield"
    STRING32 = "string32"

    @property
    def words(self) -> int:
        if self is RegType.STRING32:
            return STRING32_WORDS
        return 2 if self in (RegType.FLOAT32, RegType.INT32, RegType.UINT32) else 1


#: Registers of a string32 value: 32 ASCII characters, two per register.
STRING32_WORDS = 16
STRING32_CHARS = 2 * STRING32_WORDS


def string32_complaint(text: str) -> str | None:
    """Why `text` cannot be a string32 value (printable ASCII, ≤ 32 characters), or None."""
    if len(text) > STRING32_CHARS:
        return f"is longer than {STRING32_CHARS} characters"
    if not (text.isascii() and text.isprintable()):
        return "must be printable ASCII"
    return None


class WordOrder(enum.StrEnum):
    #: High word first: the register at the lower address holds the most significant
    #: 16 bits (pymodbus word_order="big", mbpoll default, Siemens/most PLCs).
    ABCD = "ABCD"
    #: Low word first (pymodbus word_order="little", "swapped" in many PLC tools).
    CDAB = "CDAB"


class CommandResult(enum.IntEnum):
    """Value of input register LAST_COMMAND_RESULT."""

    NONE = 0  # no command since start
    DONE = 1  # on_command returned True
    DECLINED = 2  # on_command returned False (e.g. bias re-estimation not at standstill)
    FAILED = 3  # on_command raised; the daemon logged it


@dataclass(frozen=True, slots=True)
class ServerDiagnostics:
    """The server's own numbers that appear in the input registers."""

    requests: int = 0
    exceptions: int = 0
    rejected_writes: int = 0
    clients_connected: int = 0
    command_counter: int = 0
    command_result: CommandResult = CommandResult.NONE
    rejected_frames: int = 0
    refused_connections: int = 0
    closed_connections: int = 0
    #: Identity: the gateway's version and its configured name (constant while it runs).
    version_major: int = 0
    version_minor: int = 0
    version_patch: int = 0
    device_name: str = ""


@dataclass(frozen=True, slots=True)
class Register:
    name: str
    table: Table
    #: 0-based, as on the wire.
    address: int
    type: RegType
    #: Unit of the raw register value ("" for bit fields and versions).
    unit: str
    #: raw × scale = the value in m, m/s, m/s², °C, ms or counts.
    scale: float
    description: str
    #: What fills it: a PublishedValues field, "server.<ServerDiagnostics field>",
    #: "map_version", or for holding registers "command.<Command name>".
    source: str
    #: Counters wrap modulo 2^bits; every other unsigned value saturates.
    wraps: bool = False

    @property
    def words(self) -> int:
        return self.type.words

    @property
    def plc_reference(self) -> int:
        base = PLC_INPUT_BASE if self.table is Table.INPUT else PLC_HOLDING_BASE
        return base + self.address


_I = Table.INPUT
_H = Table.HOLDING
_F32, _I32, _U32 = RegType.FLOAT32, RegType.INT32, RegType.UINT32
_U16, _I16, _BITS = RegType.UINT16, RegType.INT16, RegType.BITFIELD
_STR = RegType.STRING32

# fmt: off
REGISTERS: tuple[Register, ...] = (
    Register("MAP_VERSION", _I, 0, _U16, "", 1,
             "Version of this register map; changes when any row changes.", "map_version"),
    Register("STATUS", _I, 1, _BITS, "", 1,
             "Status bits (StatusBits): 0 VALID, 1 STANDSTILL, 2 STALE, 3 BOARD_LOST, "
             "4 SATURATED, 5 NOT_REFERENCED, 6 ESTIMATOR_FAULT, 7 HOLDING, 8 AXIS_INVALID, "
             "9 CONFIG_RELOADED, 10 BOARD_RESET, 11 SAMPLES_LOST, 12 BIAS_ESTIMATING, "
             "13 SCALED_CLAMPED, 14 POSITION_UNTRUSTED, 15 MODBUS_RTU_DOWN.", "status"),
    Register("HEARTBEAT", _I, 2, _U16, "count", 1,
             "Incremented by the daemon every publish cycle; stops when the daemon hangs.",
             "heartbeat", wraps=True),
    Register("COMMAND_COUNTER", _I, 3, _U16, "count", 1,
             "Incremented for every command received over Modbus and passed to the "
             "daemon (done, declined or failed); see LAST_COMMAND_RESULT.",
             "server.command_counter", wraps=True),
    Register("POSITION", _I, 4, _F32, "m", 1,
             "Position estimate; NaN when not available.", "position_m"),
    Register("VELOCITY", _I, 6, _F32, "m/s", 1,
             "Velocity estimate; NaN when not available.", "velocity_mps"),
    Register("ACCELERATION", _I, 8, _F32, "m/s²", 1,
             "Acceleration estimate (bias removed); NaN when not available.", "acceleration_mps2"),
    Register("POSITION_UM", _I, 10, _I32, "µm", 1e-6,
             "Position as integer; −2147483648 when not available, clamped at ±2147483647.",
             "position_m"),
    Register("VELOCITY_UM_S", _I, 12, _I32, "µm/s", 1e-6,
             "Velocity as integer; −2147483648 when not available, clamped at ±2147483647.",
             "velocity_mps"),
    Register("ACCELERATION_UM_S2", _I, 14, _I32, "µm/s²", 1e-6,
             "Acceleration as integer; −2147483648 when not available, clamped at ±2147483647.",
             "acceleration_mps2"),
    Register("SAMPLE_COUNTER", _I, 16, _U32, "count", 1,
             "Board samples processed since the daemon started.", "sample_counter", wraps=True),
    Register("LAST_SAMPLE_AGE", _I, 18, _U32, "ms", 1,
             "Age of the newest sample when the values were published; 4294967295 = no sample yet.",
             "last_sample_age_ms"),
    Register("BIAS_ESTIMATE", _I, 20, _F32, "m/s²", 1,
             "Accelerometer bias the estimator currently subtracts; NaN when unknown.",
             "bias_estimate_mps2"),
    Register("POSITION_STD", _I, 22, _F32, "m", 1,
             "1-sigma uncertainty of POSITION; NaN when unknown.", "position_std_m"),
    Register("BOARD_TEMPERATURE", _I, 24, _I16, "0.01 °C", 0.01,
             "Board temperature; −32768 when the board has no sensor.", "board_temp_c"),
    Register("LAST_COMMAND_RESULT", _I, 25, _U16, "", 1,
             "Result of the last command: 0 none yet, 1 done, 2 declined, 3 failed.",
             "server.command_result"),
    Register("LOST_SAMPLES", _I, 26, _U32, "count", 1,
             "Samples missing on the serial line (sequence gaps) since start.",
             "lost_samples", wraps=True),
    Register("CRC_ERRORS", _I, 28, _U32, "count", 1,
             "Board frames dropped for a CRC mismatch since start.", "crc_errors", wraps=True),
    Register("BOARD_RESETS", _I, 30, _U32, "count", 1,
             "Board resets seen since start.", "board_resets", wraps=True),
    Register("CAN_SEND_ERRORS", _I, 32, _U32, "count", 1,
             "CAN frames that could not be sent since start.", "can_send_errors", wraps=True),
    Register("MODBUS_REQUESTS", _I, 34, _U32, "count", 1,
             "Modbus requests handled by this server (TCP and RTU) since start.",
             "server.requests", wraps=True),
    Register("MODBUS_EXCEPTIONS", _I, 36, _U32, "count", 1,
             "Modbus exception responses sent since start.", "server.exceptions", wraps=True),
    Register("MODBUS_REJECTED_WRITES", _I, 38, _U32, "count", 1,
             "Writes refused because writes are disabled or the client is not allowed.",
             "server.rejected_writes", wraps=True),
    Register("MODBUS_CLIENTS", _I, 40, _U16, "count", 1,
             "Modbus TCP clients connected now.", "server.clients_connected"),
    Register("VERSION_MAJOR", _I, 41, _U16, "", 1,
             "Gateway software version, major part (also in device identification, FC 43/14).",
             "server.version_major"),
    Register("VERSION_MINOR", _I, 42, _U16, "", 1,
             "Gateway software version, minor part.", "server.version_minor"),
    Register("VERSION_PATCH", _I, 43, _U16, "", 1,
             "Gateway software version, patch part.", "server.version_patch"),
    Register("MODBUS_REJECTED_FRAMES", _I, 44, _U32, "count", 1,
             "Modbus frames not executed because they were malformed (bad MBAP header: the "
             "connection is closed; undecodable request: answered with an exception).",
             "server.rejected_frames", wraps=True),
    Register("MODBUS_REFUSED_CONNECTIONS", _I, 46, _U32, "count", 1,
             "Modbus TCP connections refused at once because max_connections was reached.",
             "server.refused_connections", wraps=True),
    Register("MODBUS_CLOSED_CONNECTIONS", _I, 48, _U32, "count", 1,
             "Modbus TCP connections the server closed: idle timeout, a malformed frame, or "
             "making room for a newcomer at max_connections.", "server.closed_connections", wraps=True),
    Register("DEVICE_NAME", _I, 50, _STR, "", 1,
             "[modbus] device_name: ASCII, two characters per register (first in the high "
             "byte), NUL-padded; all zero when not configured.", "server.device_name"),
    Register("STATUS_EXT", _I, 66, _BITS, "", 1,
             "Second status word (StatusExtBits): 0 SIMULATED, 1 HINT_AT_REST, 2 HINT_MOVING, "
             "3 HINT_CONFLICT, 4 OFFSET_STEP, 5 STOP_BY_HINT, 6 MQTT_DOWN.", "status_ext"),
    Register("CAN_REFUSED_COMMANDS", _I, 67, _U32, "count", 1,
             "CAN command frames refused since start: commands disabled, a CRC or length error, an "
             "unknown code, a counter not 1..3 ahead of the last accepted one (a replay).",
             "can_refused_commands", wraps=True),
    Register("MQTT_DROPPED", _I, 69, _U32, "count", 1,
             "DDATA messages the MQTT edge node dropped since start: its queue was full (the broker "
             "away longer than the backlog holds). Connected or not: STATUS_EXT bit 6.",
             "mqtt_dropped", wraps=True),
    Register("CMD_TARE", _H, 0, _U16, "", 1,
             "Write 1: position := 0 here (tare). Reads 0 (auto-clear). Writing 0 does nothing.",
             "command.TARE"),
    Register("CMD_REESTIMATE_BIAS", _H, 1, _U16, "", 1,
             "Write 1: re-estimate the accelerometer bias (only at standstill). Reads 0 "
             "(auto-clear). Writing 0 does nothing.", "command.REESTIMATE_BIAS"),
    Register("CMD_HINT_AT_REST", _H, 2, _U16, "", 1,
             "Write 1: the machine says the axis is at rest (in position). Evidence for the "
             "standstill detector, in force for estimator.hint_timeout_ms (write it again "
             "every cycle while it holds). Reads 0 (auto-clear).", "command.HINT_AT_REST"),
    Register("CMD_HINT_MOVING", _H, 3, _U16, "", 1,
             "Write 1: the machine says the axis is moving: no stop is accepted meanwhile. "
             "In force for estimator.hint_timeout_ms. Reads 0 (auto-clear).", "command.HINT_MOVING"),
    Register("CMD_HINT_UNKNOWN", _H, 4, _U16, "", 1,
             "Write 1: withdraw the hint (the accelerometer alone decides). Reads 0 "
             "(auto-clear).", "command.HINT_UNKNOWN"),
)
# fmt: on

INPUT_REGISTERS: tuple[Register, ...] = tuple(r for r in REGISTERS if r.table is Table.INPUT)
HOLDING_REGISTERS: tuple[Register, ...] = tuple(r for r in REGISTERS if r.table is Table.HOLDING)
#: Number of registers each table occupies (addresses 0 .. size-1, no gaps).
INPUT_SIZE = max(r.address + r.words for r in INPUT_REGISTERS)
HOLDING_SIZE = max(r.address + r.words for r in HOLDING_REGISTERS)
#: Rows the server refreshes at every read (its own live counters).
SERVER_ROWS: tuple[Register, ...] = tuple(
    r for r in INPUT_REGISTERS if r.source.startswith("server.")
)
#: Rows that come from the published snapshot (the rest of the input table).
VALUE_ROWS: tuple[Register, ...] = tuple(r for r in INPUT_REGISTERS if r not in SERVER_ROWS)
BY_NAME: dict[str, Register] = {r.name: r for r in REGISTERS}

INT32_NOT_AVAILABLE = -(2**31)
INT16_NOT_AVAILABLE = -(2**15)
FLOAT32_NAN_BITS = 0x7FC00000
_FLOAT32_MAX = struct.unpack(">f", b"\x7f\x7f\xff\xff")[0]


# --------------------------------------------------------------------------- #
# Encoding
# --------------------------------------------------------------------------- #
def _string_words(text: str) -> list[int]:
    data = text.encode("ascii", "replace")[: 2 * STRING32_WORDS].ljust(2 * STRING32_WORDS, b"\0")
    return list(struct.unpack(f">{STRING32_WORDS}H", data))


def _words_of_32(raw32: int, word_order: WordOrder) -> list[int]:
    high, low = (raw32 >> 16) & 0xFFFF, raw32 & 0xFFFF
    return [high, low] if word_order is WordOrder.ABCD else [low, high]


def _float32_bits(value: object) -> int:
    if value is None:
        return FLOAT32_NAN_BITS
    number = float(value)  # type: ignore[arg-type]
    if not math.isfinite(number) or abs(number) > _FLOAT32_MAX:
        return FLOAT32_NAN_BITS
    return struct.unpack(">I", struct.pack(">f", number))[0]


def _scaled_signed(value: object, scale: float, bits: int) -> tuple[int, bool]:
    """(raw, clamped) for a scaled signed integer with a reserved 'not available'."""
    if value is None:
        return -(2 ** (bits - 1)), False
    number = float(value)  # type: ignore[arg-type]
    if math.isnan(number):
        return -(2 ** (bits - 1)), False
    limit = 2 ** (bits - 1) - 1
    # ±inf is a real (if absurd) value: it clamps like any other overflow.
    scaled = number / scale if math.isfinite(number) else number
    if scaled > limit:
        return limit, True
    if scaled < -limit:
        return -limit, True
    return round(scaled), False


def _unsigned(value: object, register: Register) -> int:
    bits = 16 * register.words
    maximum = 2**bits - 1
    if value is None:
        return maximum  # "unknown" (only LAST_SAMPLE_AGE can be None)
    number = float(value)  # type: ignore[arg-type]
    if math.isnan(number):
        return maximum
    if register.wraps:
        return int(value) % (maximum + 1)  # type: ignore[call-overload]
    if number <= 0:
        return 0
    if number >= maximum:
        return maximum
    return round(number / register.scale)


def _source_value(
    register: Register, values: PublishedValues, diagnostics: ServerDiagnostics
) -> object:
    if register.source == "map_version":
        return MAP_VERSION
    if register.source.startswith("server."):
        return getattr(diagnostics, register.source.removeprefix("server."))
    return getattr(values, register.source)


def encode_register(register: Register, value: object, word_order: WordOrder) -> tuple[list[int], bool]:
    """Register words for one value, and whether a scaled integer was clamped."""
    kind = register.type
    if kind is RegType.FLOAT32:
        return _words_of_32(_float32_bits(value), word_order), False
    if kind is RegType.INT32:
        raw, clamped = _scaled_signed(value, register.scale, 32)
        return _words_of_32(raw & 0xFFFFFFFF, word_order), clamped
    if kind is RegType.INT16:
        raw, clamped = _scaled_signed(value, register.scale, 16)
        return [raw & 0xFFFF], clamped
    if kind is RegType.UINT32:
        return _words_of_32(_unsigned(value, register), word_order), False
    if kind is RegType.BITFIELD:
        return [int(value) & 0xFFFF], False  # type: ignore[call-overload]
    if kind is RegType.STRING32:
        return _string_words(str(value)), False
    return [_unsigned(value, register)], False


def encode_rows(
    rows: Sequence[Register],
    words: list[int],
    values: PublishedValues,
    diagnostics: ServerDiagnostics,
    word_order: WordOrder,
) -> bool:
    """Write `rows` into `words` (indexed by address) in place; True if any was clamped."""
    clamped_any = False
    for register in rows:
        encoded, clamped = encode_register(
            register, _source_value(register, values, diagnostics), word_order
        )
        words[register.address : register.address + register.words] = encoded
        clamped_any |= clamped
    return clamped_any


class ServerRowEncoder:
    """Writes SERVER_ROWS into an image, encoding a row again only when its value changed.

    The server answers every read from one image; between two reads usually only the
    request counter moves, and encoding all of the server's rows per request was a fifth
    of the gateway's CPU with 50 polling clients. `diagnostics` is anything with the
    fields of ServerDiagnostics (the server passes its live counters, not a copy).
    """

    def __init__(self, word_order: WordOrder) -> None:
        self._word_order = word_order
        self._rows = tuple((r, r.source.removeprefix("server.")) for r in SERVER_ROWS)
        self._last: list[object] = [None] * len(self._rows)

    def write(self, words: list[int], diagnostics: object, *, all_rows: bool = False) -> None:
        """Bring the server's rows in `words` up to date; `all_rows` after `words` was
        replaced by a new image (whose server rows are not these)."""
        last = self._last
        for i, (register, field) in enumerate(self._rows):
            value = getattr(diagnostics, field)
            if all_rows or value != last[i]:
                encoded, _ = encode_register(register, value, self._word_order)
                words[register.address : register.address + register.words] = encoded
                last[i] = value


_NO_DIAGNOSTICS = ServerDiagnostics()  # (VALUE_ROWS read none of it)


def write_value_rows(words: list[int], values: PublishedValues, word_order: WordOrder = WordOrder.ABCD) -> None:
    """A new snapshot into an input image in place: its rows (VALUE_ROWS), SCALED_CLAMPED
    in STATUS when a value was clamped; the server's own rows are left as they are (the
    server keeps them with a ServerRowEncoder)."""
    if encode_rows(VALUE_ROWS, words, values, _NO_DIAGNOSTICS, word_order):
        words[BY_NAME["STATUS"].address] |= int(StatusBits.SCALED_CLAMPED)


def encode_input_registers(
    values: PublishedValues,
    diagnostics: ServerDiagnostics = ServerDiagnostics(),
    word_order: WordOrder = WordOrder.ABCD,
) -> list[int]:
    """The whole input register image (address 0 .. INPUT_SIZE-1) for one snapshot."""
    words = [0] * INPUT_SIZE
    clamped = encode_rows(INPUT_REGISTERS, words, values, diagnostics, word_order)
    if clamped:
        status = BY_NAME["STATUS"]
        words[status.address] |= int(StatusBits.SCALED_CLAMPED)
    return words


def decode_register(register: Register, words: Sequence[int], word_order: WordOrder) -> float | int | str:
    """Raw value of one register from its words (floats as float, integers signed/unsigned,
    text as str without its NUL padding).

    Multiply by `register.scale` for the value in its unit. Sentinels are returned as
    they are (−2147483648, −32768, NaN); the caller interprets them.
    """
    if register.type is RegType.STRING32:
        return struct.pack(f">{STRING32_WORDS}H", *words[:STRING32_WORDS]).rstrip(b"\0").decode("ascii", "replace")
    if register.words == 2:
        first, second = words[0], words[1]
        high, low = (first, second) if word_order is WordOrder.ABCD else (second, first)
        raw = (high << 16) | low
        if register.type is RegType.FLOAT32:
            return struct.unpack(">f", raw.to_bytes(4, "big"))[0]
        if register.type is RegType.INT32:
            return raw - (1 << 32) if raw & 0x80000000 else raw
        return raw
    raw = words[0]
    if register.type is RegType.INT16:
        return raw - (1 << 16) if raw & 0x8000 else raw
    return raw
