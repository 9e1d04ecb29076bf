"""Modbus TCP server and optional Modbus RTU server publishing `PublishedValues`.

Built on pymodbus 3.16's server classes and its SimDevice datastore (the older
ModbusServerContext/ModbusSequentialDataBlock are deprecated in 3.16 and only wrapped
into SimDevice). The register values live here, not in pymodbus: `update()` encodes a
whole input register image and swaps it in with one assignment, and the SimDevice
`action` hook copies the current image into pymodbus's register list right before a
read is answered. Everything runs in the event loop thread and nothing awaits between
the copy and the slice pymodbus returns, so a client never sees half of an old and half
of a new 32-bit value. Both servers (TCP and RTU) read the same image.

Who may write, and what a write does, is decided per request in a request handler
subclass: pymodbus gives the datastore no client address, but each TCP connection has
its own handler whose transport knows the peer (pymodbus issue #2159 has the same
question; no public hook exists in 3.x).

Exception codes this server answers with:
- 01 ILLEGAL FUNCTION: function code not supported here (only 3, 4, 6, 16, 23 are), or
  a write refused by policy (writes disabled, client address not allowed, RTU writes
  not allowed). pymodbus also answers 01 to requests it cannot decode.
- 02 ILLEGAL DATA ADDRESS: any register outside the map (from pymodbus's datastore).
- 03 ILLEGAL DATA VALUE: a command register written with anything but 0 or 1, or a
  count/byte-count that does not fit (pymodbus).
- 04 SERVER DEVICE FAILURE: the command reached the daemon and was declined or failed
  (LAST_COMMAND_RESULT tells which).
"""

from __future__ import annotations

import asyncio
import contextvars
import dataclasses
import ipaddress
import logging
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.transaction import TransactionManager

from .modbus_map import (
    HOLDING_REGISTERS,
    HOLDING_SIZE,
    INPUT_SIZE,
    SERVER_ROWS,
    CommandResult,
    ServerDiagnostics,
    WordOrder,
    encode_input_registers,
    encode_rows,
)
from .published_values import (
    NOTHING_PUBLISHED,
    Command,
    CommandCallback,
    PublishedValues,
    ValuesSource,
    current,
)

log = logging.getLogger(__name__)

READ_HOLDING = 3
READ_INPUT = 4
WRITE_SINGLE = 6
WRITE_MULTIPLE = 16
READ_WRITE_MULTIPLE = 23
SUPPORTED_FUNCTIONS = frozenset({READ_HOLDING, READ_INPUT, WRITE_SINGLE, WRITE_MULTIPLE, READ_WRITE_MULTIPLE})
WRITE_FUNCTIONS = frozenset({WRITE_SINGLE, WRITE_MULTIPLE, READ_WRITE_MULTIPLE})

#: holding address -> command, from the map
_COMMAND_AT: dict[int, Command] = {
    r.address: Command[r.source.removeprefix("command.")] for r in HOLDING_REGISTERS
}

#: The wire and peer of the request being executed, e.g. "modbus-tcp:10.0.0.7:50312".
#: Set by the request handler around the datastore call; the SimDevice action reads it.
_REQUEST_SOURCE: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_request_source")


class ModbusServerError(Exception):
    """The Modbus server could not start (port in use, serial port missing, bad config).

    Local to this module until the lead reconciles it with drivers/errors.py.
    """


@dataclass(frozen=True, slots=True)
class ModbusServerConfig:
    """Settings; the names match the [modbus] section of the daemon's config."""

    tcp_enabled: bool = True
    host: str = "127.0.0.1"
    #: 0 = let the OS choose (tests); read the bound port from `ModbusServer.tcp_port`.
    port: int = 5020
    #: The RTU server answers only this unit id; other ids and broadcasts (0) belong to
    #: other devices on a shared RS-485 line and get no answer. TCP answers any unit id
    #: (the IP address is the device address there; PLCs send 0, 1 or 255).
    unit_id: int = 1
    word_order: WordOrder = WordOrder.ABCD
    #: Master switch for the command registers on every wire.
    writes_enabled: bool = False
    #: TCP clients allowed to write when writes are enabled: addresses or networks
    #: ("192.168.10.5", "10.0.0.0/24"). Empty = nobody; "0.0.0.0/0" = every IPv4 client.
    write_allow: tuple[str, ...] = ("127.0.0.1",)
    rtu_enabled: bool = False
    #: Serial device (or pyserial URL) of the RTU server.
    rtu_port: str = "/dev/ttyUSB1"
    rtu_baudrate: int = 19200
    #: Modbus over serial line specifies even parity as the default.
    rtu_parity: str = "E"
    rtu_bytesize: int = 8
    rtu_stopbits: int = 1
    #: RTU has no client address: whether the RS-485 master may write (also needs
    #: writes_enabled).
    rtu_writes_enabled: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ModbusServerError(f"port {self.port} outside 0..65535")
        if not 0 <= self.unit_id <= 247 or (self.rtu_enabled and self.unit_id == 0):
            raise ModbusServerError(
                f"unit_id {self.unit_id} outside 1..247 (0 is the RTU broadcast address)"
            )
        if self.rtu_parity not in ("N", "E", "O"):
            raise ModbusServerError(f"rtu_parity {self.rtu_parity!r} is not N, E or O")
        try:
            object.__setattr__(self, "word_order", WordOrder(self.word_order))
        except ValueError as err:
            raise ModbusServerError(f"word_order {self.word_order!r} is not ABCD or CDAB") from err
        object.__setattr__(self, "write_allow", tuple(self.write_allow))
        self.allowed_networks()  # validates

    def allowed_networks(self) -> tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, ...]:
        try:
            return tuple(ipaddress.ip_network(entry, strict=False) for entry in self.write_allow)
        except ValueError as err:
            raise ModbusServerError(f"write_allow: {err}") from err


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


class ModbusServer:
    """Serves the register map over Modbus TCP and, if configured, Modbus RTU.

    Use from one asyncio event loop: `await start()`, then `update(values)` whenever
    the daemon has new values, `await stop()` at the end.
    """

    def __init__(
        self,
        config: ModbusServerConfig,
        on_command: CommandCallback | None = None,
        before_read: Callable[[], object] | None = None,
    ) -> None:
        self.config = config
        self._on_command = on_command
        # called before each read of the input registers: the daemon takes the bytes
        # the board sent since its last wakeup (and calls update() if there were any)
        self._before_read = before_read
        self._networks = config.allowed_networks()
        self._counters = ModbusCounters()
        self._command_counter = 0
        self._command_result = CommandResult.NONE
        self._image: list[int] = encode_input_registers(NOTHING_PUBLISHED, word_order=config.word_order)
        self._pending: ValuesSource | None = None
        self._servers: list[_TcpServer | _SerialServer] = []
        self._tcp: _TcpServer | None = None
        self._handlers: set[_GatewayRequestHandler] = set()

    # ---------------------------------------------------------------- API --
    def update(self, values: ValuesSource) -> None:
        """Publish a new snapshot (or a function returning it); the next read of any
        client sees all of it."""
        # Encoding (and, for a function, building the snapshot) is deferred to the next
        # read: the daemon updates 500 times a second, clients read far less often (or
        # never), and an image nobody reads costs CPU. Reads and updates run in the same
        # event loop thread, so a read encodes the newest snapshot as a whole, never a mix.
        self._pending = values

    @property
    def counters(self) -> ModbusCounters:
        return self._counters

    @property
    def tcp_port(self) -> int | None:
        """The bound TCP port (useful with port=0), None if TCP is not running."""
        if self._tcp is None or self._tcp.transport is None:
            return None
        sockets = getattr(self._tcp.transport, "sockets", None) or ()
        return sockets[0].getsockname()[1] if sockets else None

    async def start(self) -> None:
        if self._servers:
            raise ModbusServerError("server already started")
        device = self._device()
        cfg = self.config
        try:
            if cfg.tcp_enabled:
                self._tcp = _TcpServer(self, context=device, address=(cfg.host, cfg.port))
                self._servers.append(self._tcp)
                await self._tcp.serve_forever(background=True)
            if cfg.rtu_enabled:
                rtu = _SerialServer(
                    self,
                    context=device,
                    framer=FramerType.RTU,
                    port=cfg.rtu_port,
                    baudrate=cfg.rtu_baudrate,
                    parity=cfg.rtu_parity,
                    bytesize=cfg.rtu_bytesize,
                    stopbits=cfg.rtu_stopbits,
                )
                self._servers.append(rtu)
                await rtu.serve_forever(background=True)
        except (RuntimeError, OSError) as err:
            # pymodbus reports a failed listen/open as RuntimeError after logging the
            # OSError; close whatever did start.
            await self.stop()
            raise ModbusServerError(f"cannot start Modbus server: {err}") from err
        log.info(
            "Modbus server started (tcp port %s, rtu %s)",
            self.tcp_port,
            cfg.rtu_port if cfg.rtu_enabled else "off",
        )

    async def stop(self) -> None:
        servers, self._servers = self._servers, []
        for server in servers:
            await server.shutdown()
        for handler in list(self._handlers):
            handler.cancel_pending()
        self._handlers.clear()
        self._tcp = None

    # ------------------------------------------------------------ internals --
    def _device(self) -> SimDevice:
        # Separate tables (tuple form): coils, discrete inputs, holding, input. Coils and
        # discrete inputs must exist for pymodbus but are refused before they are reached.
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

    def _diagnostics(self) -> ServerDiagnostics:
        c = self._counters
        return ServerDiagnostics(
            requests=c.requests,
            exceptions=c.exceptions,
            rejected_writes=c.rejected_writes,
            clients_connected=c.clients_connected,
            command_counter=self._command_counter,
            command_result=self._command_result,
        )

    def _bump(self, **deltas: int) -> None:
        c = self._counters
        self._counters = dataclasses.replace(
            c, **{name: getattr(c, name) + delta for name, delta in deltas.items()}
        )

    def _refusal(self, function_code: int, handler: _GatewayRequestHandler) -> ExcCodes | None:
        """Why this request must not reach the datastore, or None."""
        if function_code not in SUPPORTED_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        if function_code not in WRITE_FUNCTIONS:
            return None
        if self.config.writes_enabled and (
            self.config.rtu_writes_enabled if handler.is_rtu else self._ip_allowed(handler.peer_ip)
        ):
            return None
        self._bump(rejected_writes=1)
        log.warning("Modbus write refused from %s", handler.source)
        return ExcCodes.ILLEGAL_FUNCTION

    def _ip_allowed(self, peer_ip: str | None) -> bool:
        if peer_ip is None:
            return False
        address = ipaddress.ip_address(peer_ip.split("%", 1)[0])
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped
        return any(address in network for network in self._networks)

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
        del start_address, count
        if function_code == READ_INPUT:
            # One slice assignment from the current image, then the live server rows;
            # no await until pymodbus slices the answer out of this list.
            if self._before_read is not None:
                self._before_read()
            if self._pending is not None:
                self._image = encode_input_registers(current(self._pending), word_order=self.config.word_order)
                self._pending = None
            current_registers[0:INPUT_SIZE] = self._image
            encode_rows(
                SERVER_ROWS, current_registers, NOTHING_PUBLISHED, self._diagnostics(), self.config.word_order
            )
            return None
        if set_values is None:
            return None  # holding read: command registers rest at 0
        return self._write_commands(address, current_registers, [int(v) for v in set_values])

    def _write_commands(self, address: int, current_registers: list[int], values: Sequence[int]) -> ExcCodes | None:
        if any(value not in (0, 1) for value in values):
            return ExcCodes.ILLEGAL_VALUE
        source = _REQUEST_SOURCE.get("modbus")
        failed = False
        for offset, value in enumerate(values):
            command = _COMMAND_AT.get(address + offset)
            if value == 1 and command is not None:
                failed |= self._execute(command, source) is not CommandResult.DONE
        if failed:
            return ExcCodes.DEVICE_FAILURE
        # Auto-clear after the response is built: FC06 answers with the register read
        # back, which must echo the written value, so the clear runs on the next loop
        # iteration (the handler builds and sends the response without awaiting).
        asyncio.get_running_loop().call_soon(_clear_registers, current_registers)
        return None

    def _execute(self, command: Command, source: str) -> CommandResult:
        if self._on_command is None:
            result = CommandResult.DECLINED
        else:
            try:
                result = CommandResult.DONE if self._on_command(command, source) else CommandResult.DECLINED
            except Exception:  # the daemon's bug must not take the server down
                log.exception("on_command(%s) from %s raised", command.name, source)
                result = CommandResult.FAILED
        self._command_counter += 1
        self._command_result = result
        self._bump(
            commands_done=int(result is CommandResult.DONE),
            commands_declined=int(result is CommandResult.DECLINED),
            commands_failed=int(result is CommandResult.FAILED),
        )
        log.info("Modbus command %s from %s: %s", command.name, source, result.name)
        return result


def _clear_registers(registers: list[int]) -> None:
    registers[0:HOLDING_SIZE] = [0] * HOLDING_SIZE


class _GatewayRequestHandler(ServerRequestHandler):
    """One per TCP connection (one for the serial line): admission and accounting."""

    server: _TcpServer | _SerialServer

    def __init__(self, owner: _TcpServer | _SerialServer) -> None:
        super().__init__(owner, owner.trace_packet, owner.trace_pdu, owner.trace_connect)
        self.gateway = owner.gateway
        self.is_rtu = owner.is_rtu
        self.peer_ip: str | None = None
        self.source = "modbus-rtu" if self.is_rtu else "modbus-tcp"
        self._counted_client = False
        self._tasks: set[asyncio.Task[None]] = set()
        self.gateway._handlers.add(self)

    def callback_connected(self) -> None:
        super().callback_connected()
        if self.is_rtu:
            self.source = f"modbus-rtu:{self.gateway.config.rtu_port}:unit{self.gateway.config.unit_id}"
            return
        peer = self.transport.get_extra_info("peername") if self.transport else None
        if peer:
            self.peer_ip = str(peer[0])
            self.source = f"modbus-tcp:{peer[0]}:{peer[1]}"
        self._counted_client = True
        self.gateway._bump(clients_connected=1, connections_total=1)

    def callback_disconnected(self, exc: Exception | None) -> None:
        super().callback_disconnected(exc)
        if self._counted_client:
            self._counted_client = False
            self.gateway._bump(clients_connected=-1)
        self.gateway._handlers.discard(self)

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        """Decode every complete request in `data` and schedule each with its PDU bound.

        Replaces ServerRequestHandler.callback_data, which handles one request per
        call (a second request in the same TCP segment waited for more data) and lets
        the scheduled task re-read `last_pdu` later (a newer request could replace the
        one that was checked).
        """
        used_total = 0
        while used_total < len(data):
            chunk = data[used_total:]
            try:
                used = TransactionManager.callback_data(self, chunk, addr)
            except ModbusIOException as exc:
                self._answer_undecodable(chunk, exc, addr)
                return len(data)
            if self.last_pdu is not None:
                task = asyncio.ensure_future(self._handle(self.last_pdu, addr))
                self._tasks.add(task)
                task.add_done_callback(self._tasks.discard)
                self.last_pdu = None
            if not used:
                break  # incomplete frame: wait for more bytes
            used_total += used
        return used_total

    def _answer_undecodable(self, frame: bytes, exc: ModbusIOException, addr: tuple | None) -> None:
        # pymodbus answers these with function code 0x80; answer with the request's own
        # function code as the Modbus spec wants: 01 for a function we do not serve, 03
        # for a known function whose quantity/byte count/length is wrong.
        _, _, _, pdu_bytes = self.framer.decode(frame)
        function_code = pdu_bytes[0] & 0x7F if pdu_bytes else 0
        code = ExcCodes.ILLEGAL_VALUE if function_code in SUPPORTED_FUNCTIONS else ExcCodes.ILLEGAL_FUNCTION
        dev_id = exc.dev_id if exc.dev_id is not None else 0
        response = ExceptionResponse(function_code, code, device_id=dev_id, transaction=exc.transaction_id or 0)
        if not self.is_rtu or dev_id == self.gateway.config.unit_id:
            self.gateway._bump(requests=1)
        self.server_send(response, addr)

    def handle_later(self) -> None:  # pragma: no cover - callback_data schedules directly
        raise RuntimeError("handle_later is not used by the gateway handler")

    async def handle_request(self) -> None:  # pragma: no cover - see callback_data
        raise RuntimeError("handle_request is not used by the gateway handler")

    def cancel_pending(self) -> None:
        for task in list(self._tasks):
            task.cancel()

    async def _handle(self, pdu: ModbusPDU, addr: tuple | None) -> None:
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # addressed to another device on the line (or broadcast): stay silent
        self.gateway._bump(requests=1)
        refusal = self.gateway._refusal(pdu.function_code, self)
        if refusal is not None:
            response: ModbusPDU = ExceptionResponse(pdu.function_code, refusal)
        else:
            source_token = _REQUEST_SOURCE.set(self.source)
            try:
                response = await pdu.datastore_update(self.server.context, pdu.dev_id)
            except Exception as exc:  # a datastore bug answers 04, the server lives on
                log.error("Modbus request %s failed: %s\n%s", pdu, exc, traceback.format_exc())
                response = ExceptionResponse(pdu.function_code, ExcCodes.DEVICE_FAILURE)
            finally:
                _REQUEST_SOURCE.reset(source_token)
        response.transaction_id = pdu.transaction_id
        response.dev_id = pdu.dev_id
        self.server_send(response, addr)

    def server_send(self, pdu: ModbusPDU | None, addr: tuple | None) -> None:
        if pdu is None:
            return
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # e.g. pymodbus's answer to an undecodable frame for another device
        if isinstance(pdu, ExceptionResponse):
            self.gateway._bump(exceptions=1)
        super().server_send(pdu, addr)


class _TcpServer(ModbusTcpServer):
    is_rtu = False

    def __init__(self, gateway: ModbusServer, **kwargs: object) -> None:
        self.gateway = gateway
        super().__init__(**kwargs)  # type: ignore[arg-type]

    def callback_new_connection(self) -> _GatewayRequestHandler:
        return _GatewayRequestHandler(self)


class _SerialServer(ModbusSerialServer):
    is_rtu = True

    def __init__(self, gateway: ModbusServer, **kwargs: object) -> None:
        self.gateway = gateway
        super().__init__(**kwargs)  # type: ignore[arg-type]

    def callback_new_connection(self) -> _GatewayRequestHandler:
        return _GatewayRequestHandler(self)
