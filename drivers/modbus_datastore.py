"""What the Modbus registers hold: the input image, the command registers, the counters.

The register values live here, not in pymodbus. `InputImage.update()` keeps the newest
snapshot and the next read encodes it as a whole (the daemon updates 500 times a second,
clients read far less often, or never: an image nobody reads costs no CPU); reads and
updates run in the same event loop thread, so a client never sees half of an old and
half of a new 32-bit value. Input reads never go through pymodbus's datastore (its
per-register checks and a copy of the whole table per read cost as much as the rest of
the request). The holding table is pymodbus's SimDevice (pymodbus 3.16; the older
ModbusServerContext/ModbusSequentialDataBlock are deprecated there): its `action` hook
turns a write of 1 into a command (`CommandRegisters`), and the registers clear again.
"""
from __future__ import annotations

import asyncio
import contextvars
import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.simulator import DataType, SimData, SimDevice

from .modbus_map import (
    HOLDING_REGISTERS,
    HOLDING_SIZE,
    INPUT_SIZE,
    CommandResult,
    ServerDiagnostics,
    ServerRowEncoder,
    WordOrder,
    encode_input_registers,
    write_value_rows,
)
from .peer_log import PeerLogLimiter
from .published_values import NOTHING_PUBLISHED, Command, CommandCallback, ValuesSource, current

log = logging.getLogger(__name__)

#: holding address -> command, from the map
COMMAND_AT: dict[int, Command] = {
    r.address: Command[r.source.removeprefix("command.")] for r in HOLDING_REGISTERS
}

#: The wire and peer of the request being executed, e.g. "modbus-tcp:10.0.0.7:50312".
#: Set by the request handler around the datastore call; the SimDevice action reads it
#: (pymodbus gives the datastore no client address).
REQUEST_SOURCE: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_request_source")


@dataclass(frozen=True, slots=True)
class ModbusCounters:
    """A snapshot of the server's counters (`ModbusServer.counters`)."""

    requests: int = 0
    exceptions: int = 0
    rejected_writes: int = 0
    clients_connected: int = 0
    connections_total: int = 0
    commands_done: int = 0
    commands_declined: int = 0
    commands_failed: int = 0
    #: Frames not executed: a bad MBAP header (connection closed) or an undecodable request.
    rejected_frames: int = 0
    #: Connections refused at once because max_connections was reached.
    refused_connections: int = 0
    #: Connections the server closed: idle, a bad frame, room for a priority client.
    closed_connections: int = 0
    #: accept() failures (e.g. EMFILE: out of file descriptors), each logged at most once
    #: per interval.
    accept_errors: int = 0
    #: Attempts to open the RTU port that failed (missing, lost).
    rtu_open_failures: int = 0


_COUNTER_FIELDS = tuple(f.name for f in dataclasses.fields(ModbusCounters))


def _tally_fields() -> list[tuple[str, object, dataclasses.Field]]:
    counters = {f.name: f for f in dataclasses.fields(ModbusCounters)}
    extra = [f for f in dataclasses.fields(ServerDiagnostics) if f.name not in counters]
    return [(f.name, f.type, dataclasses.field(default=f.default)) for f in (*counters.values(), *extra)]


def _bump(tally: object, **deltas: int) -> None:
    """Add each delta to its counter."""
    for name, delta in deltas.items():
        setattr(tally, name, getattr(tally, name) + delta)


def _snapshot(tally: object) -> ModbusCounters:
    return ModbusCounters(**{name: getattr(tally, name) for name in _COUNTER_FIELDS})


#: The server's live numbers: ModbusCounters' fields and the rest of ServerDiagnostics'
#: (made from both, so that it cannot miss one). Mutable: bumped per request (a new frozen
#: snapshot per request cost more than the request's own handling); `snapshot()` hands out
#: frozen copies, the register image reads it as its ServerDiagnostics.
ServerTally = dataclasses.make_dataclass(
    "ServerTally", _tally_fields(), slots=True, namespace={"bump": _bump, "snapshot": _snapshot}
)


class InputImage:
    """The input table a read answers: the newest snapshot's image with the server's rows
    (from the tally) written over it, only those that changed."""

    def __init__(self, word_order: WordOrder, tally: ServerTally) -> None:
        self._word_order = word_order
        self._tally = tally
        self._words: list[int] = encode_input_registers(NOTHING_PUBLISHED, word_order=word_order)
        self._server_rows = ServerRowEncoder(word_order)
        self._server_rows.write(self._words, tally, all_rows=True)
        self._pending: ValuesSource | None = None

    def update(self, values: ValuesSource) -> None:
        """Keep the newest snapshot (or a function returning it); encoded on the next read."""
        self._pending = values

    def words(self, address: int, count: int) -> list[int]:
        """A copy of `count` words from `address` (within the table), the newest snapshot
        encoded first (each read gets a slice, a copy: writing the image in place changes
        no answer given)."""
        image = self._words
        if self._pending is not None:
            write_value_rows(image, current(self._pending), self._word_order)
            self._pending = None
        self._server_rows.write(image, self._tally)
        return image[address : address + count]

    @staticmethod
    def holds(address: int, count: int) -> bool:
        return address >= 0 and count >= 1 and address + count <= INPUT_SIZE


class CommandRegisters:
    """The holding table: a write of 1 to a command register runs that command (through
    `on_command`), a write of 0 does nothing, anything else is refused; the registers
    read 0 again after the answer."""

    def __init__(self, on_command: CommandCallback | None, tally: ServerTally, peer_log: PeerLogLimiter) -> None:
        self._on_command = on_command
        self._tally = tally
        self._peer_log = peer_log

    def device(self) -> SimDevice:
        """pymodbus's datastore with this hook. Separate tables (tuple form): coils,
        discrete inputs, holding, input; coils and discrete inputs must exist for pymodbus
        but are refused before they are reached, input reads never reach it."""
        return SimDevice(
            id=0,  # 0 = answer every unit id; the RTU handler filters unit_id
            simdata=(
                [SimData(0, values=0, datatype=DataType.BITS)],
                [SimData(0, values=0, datatype=DataType.BITS)],
                [SimData(0, count=HOLDING_SIZE, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, count=INPUT_SIZE, values=0, datatype=DataType.REGISTERS)],
            ),
            action=self._on_register_access,
        )

    async def _on_register_access(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        current_registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """pymodbus SimDevice action: called before every datastore access.

        `address` is the request's start address, `current_registers` pymodbus's list
        for the whole table (starting at address 0), `set_values` None for reads.
        """
        del function_code, start_address, count
        if set_values is None:
            return None  # holding read: command registers rest at 0
        return self.write(address, current_registers, [int(v) for v in set_values])

    def write(self, address: int, current_registers: list[int], values: Sequence[int]) -> ExcCodes | None:
        if any(value not in (0, 1) for value in values):
            return ExcCodes.ILLEGAL_VALUE
        source = REQUEST_SOURCE.get("modbus")
        failed = False
        for offset, value in enumerate(values):
            command = COMMAND_AT.get(address + offset)
            if value == 1 and command is not None:
                failed |= self.execute(command, source) is not CommandResult.DONE
        if failed:
            return ExcCodes.DEVICE_FAILURE
        # Auto-clear after the response is built: FC06 answers with the register read
        # back, which must echo the written value, so the clear runs on the next loop
        # iteration (the handler builds and sends the response without awaiting).
        asyncio.get_running_loop().call_soon(_clear_registers, current_registers)
        return None

    def execute(self, command: Command, source: str) -> CommandResult:
        if self._on_command is None:
            result = CommandResult.DECLINED
        else:
            try:
                result = CommandResult.DONE if self._on_command(command, source) else CommandResult.DECLINED
            except Exception:  # the daemon's bug must not take the server down
                log.exception("on_command(%s) from %s raised", command.name, source)
                result = CommandResult.FAILED
        self._tally.command_counter += 1
        self._tally.command_result = result
        self._tally.bump(
            commands_done=int(result is CommandResult.DONE),
            commands_declined=int(result is CommandResult.DECLINED),
            commands_failed=int(result is CommandResult.FAILED),
        )
        # a PLC writes the hint every cycle: one line per source, command and result and
        # peer_log_interval_s, with a count
        self._peer_log.note(source, f"command {command.name} {result.name}",
                            f"Modbus command {command.name}: {result.name}", logging.INFO)
        return result


def _clear_registers(registers: list[int]) -> None:
    registers[0:HOLDING_SIZE] = [0] * HOLDING_SIZE


