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

Connections (TCP), so a PLC is never locked out and a bad peer costs bounded resources
(policy in drivers/modbus_admission.py): at most `max_connections`; at the limit a
newcomer gets in by closing the connection that has done least, never a priority client
(write_allow and priority_clients) for a non-priority one; idle connections are closed
after `idle_timeout_s`. The MBAP header of every frame is checked here before pymodbus sees it:
a protocol id other than 0 or a length outside 2..254 cannot be resynchronised on a byte
stream, so the connection is closed at once (counted in MODBUS_REJECTED_FRAMES) instead
of waiting deaf for bytes that never complete the frame. Requests are answered in the
order they arrived, however many come in one segment: past MAX_QUEUED_REQUESTS waiting,
the server stops reading that connection until it has caught up (and stops reading a
client that does not read its answers), so memory stays bounded and nothing is dropped.
What peers do wrong is logged at most once per peer and interval (drivers/peer_log.py).

Device identification (function 43 / MEI 14, read codes 1–4) is answered from this
server's `DeviceIdentity` (drivers/modbus_identity.py).

Exception codes this server answers with:
- 01 ILLEGAL FUNCTION: function code not supported here (only 3, 4, 6, 16, 23, 43/14 are), or
  a write refused by policy (writes disabled, client address not allowed, RTU writes
  not allowed). pymodbus also answers 01 to requests it cannot decode.
- 02 ILLEGAL DATA ADDRESS: any register outside the map (from pymodbus's datastore), or a
  device identification object that does not exist (read code 4).
- 03 ILLEGAL DATA VALUE: a command register written with anything but 0 or 1, a
  count/byte-count that does not fit (pymodbus), or a device identification read code
  other than 1–4.
- 04 SERVER DEVICE FAILURE: the command reached the daemon and was declined or failed
  (LAST_COMMAND_RESULT tells which).
"""

from __future__ import annotations

import asyncio
import collections
import contextvars
import dataclasses
import logging
import math
import struct
import termios
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerType
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.mei_message import ReadDeviceInformationRequest, ReadDeviceInformationResponse
from pymodbus.pdu.register_message import ReadInputRegistersResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.transaction import TransactionManager

from .modbus_admission import Connection, Network, address_in, admit, idle, parse_networks
from .modbus_identity import CONFORMITY_LEVEL, DeviceIdentity, device_information, version_numbers
from .modbus_map import (
    BY_NAME,
    HOLDING_REGISTERS,
    HOLDING_SIZE,
    INPUT_SIZE,
    MAP_VERSION,
    CommandResult,
    ServerDiagnostics,
    ServerRowEncoder,
    WordOrder,
    encode_input_registers,
    string32_complaint,
    write_value_rows,
)
from .modbus_ports import RtuPortProblem, probe_rtu_port, tcp_listen_problem
from .peer_log import PeerLogLimiter
from .published_values import (
    NOTHING_PUBLISHED,
    Command,
    CommandCallback,
    StatusBits,
    ValuesSource,
    current,
)

log = logging.getLogger(__name__)

READ_HOLDING = 3
READ_INPUT = 4
WRITE_SINGLE = 6
WRITE_MULTIPLE = 16
READ_WRITE_MULTIPLE = 23
ENCAPSULATED_INTERFACE = 43  # with MEI type 14: read device identification
SUPPORTED_FUNCTIONS = frozenset(
    {READ_HOLDING, READ_INPUT, WRITE_SINGLE, WRITE_MULTIPLE, READ_WRITE_MULTIPLE, ENCAPSULATED_INTERFACE}
)
WRITE_FUNCTIONS = frozenset({WRITE_SINGLE, WRITE_MULTIPLE, READ_WRITE_MULTIPLE})

#: MBAP header: transaction id, protocol id, length (2 bytes each), unit id.
MBAP_HEADER_BYTES = 7
#: The MBAP length counts the unit id and the PDU; a PDU is 1..253 bytes.
MBAP_LENGTH_MIN, MBAP_LENGTH_MAX = 2, 254
#: Requests of one connection waiting for their answer; beyond, the server stops reading
#: that connection until it caught up (TCP flow control pushes back on the client).
MAX_QUEUED_REQUESTS = 32
#: How often idle connections are looked for and held-back peer log counts written.
SWEEP_INTERVAL_S = 1.0
#: Reopening a missing RTU port: first wait, longest wait (doubling), like the board port.
RTU_RETRY_MIN_S, RTU_RETRY_MAX_S = 0.2, 5.0
_STATUS_ADDRESS = BY_NAME["STATUS"].address
_ACCEPT_ERROR = "socket.accept() out of system resource"
# asyncio pauses accepting for 1 s after EMFILE (asyncio.constants.ACCEPT_RETRY_DELAY)
_ACCEPT_RETRY_MARGIN_S = 1.5


def _is_late_accept_retry(context: dict) -> bool:
    """asyncio's accept retry (BaseSelectorEventLoop._start_serving) failing on a listener
    that was closed meanwhile (its socket's fd is −1)."""
    err = context.get("exception")
    handle = context.get("handle")
    return (isinstance(err, ValueError) and "Invalid file descriptor: -1" in str(err)
            and handle is not None and "_start_serving" in repr(handle))


class _PymodbusDuplicates(logging.Filter):
    """Drops pymodbus's lines that this server says better: one per undecodable frame
    (counted in MODBUS_REJECTED_FRAMES and logged once per peer and interval here), and
    a failed listen (ModbusServerError names the cause)."""

    DROPPED = ("Unable to decode frame", "Failed to start server")

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.DROPPED)


_PYMODBUS_LOG = logging.getLogger("pymodbus.logging")
_PYMODBUS_DUPLICATES = _PymodbusDuplicates()

#: holding address -> command, from the map
_COMMAND_AT: dict[int, Command] = {
    r.address: Command[r.source.removeprefix("command.")] for r in HOLDING_REGISTERS
}

#: The wire and peer of the request being executed, e.g. "modbus-tcp:10.0.0.7:50312".
#: Set by the request handler around the datastore call; the SimDevice action reads it.
_REQUEST_SOURCE: contextvars.ContextVar[str] = contextvars.ContextVar("modbus_request_source")


class ModbusServerError(Exception):
    """The Modbus server could not start (port in use, serial port settings refused, bad config).

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
    #: They are priority clients too (see max_connections).
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
    #: TCP connections served at once. At the limit a newcomer gets in by closing the
    #: connection that has done least (modbus_admission), never a priority one for a
    #: non-priority newcomer (refused when only priority ones are left).
    max_connections: int = 64
    #: Addresses or networks that always get in, besides those in write_allow.
    priority_clients: tuple[str, ...] = ()
    #: A TCP connection without a complete request for this long is closed; 0 = never.
    idle_timeout_s: float = 60.0
    #: What a peer does wrong is logged at most once per peer and interval, with a count.
    peer_log_interval_s: float = 10.0
    #: Served in device identification (object 6) and the DEVICE_NAME registers.
    device_name: str = ""

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
        if not 1 <= self.max_connections <= 10_000:
            raise ModbusServerError(f"max_connections {self.max_connections} outside 1..10000")
        if not (math.isfinite(self.idle_timeout_s) and self.idle_timeout_s >= 0):
            raise ModbusServerError(f"idle_timeout_s {self.idle_timeout_s} must be a finite number ≥ 0")
        if not (math.isfinite(self.peer_log_interval_s) and self.peer_log_interval_s > 0):
            raise ModbusServerError(f"peer_log_interval_s {self.peer_log_interval_s} must be > 0")
        complaint = string32_complaint(self.device_name)  # it fills the DEVICE_NAME registers
        if complaint:
            raise ModbusServerError(f"device_name {self.device_name!r:.60}: {complaint}")
        object.__setattr__(self, "write_allow", tuple(self.write_allow))
        object.__setattr__(self, "priority_clients", tuple(self.priority_clients))
        self.allowed_networks()  # validates
        self.priority_networks()

    def allowed_networks(self) -> tuple[Network, ...]:
        try:
            return parse_networks(self.write_allow)
        except ValueError as err:
            raise ModbusServerError(f"write_allow: {err}") from err

    def priority_networks(self) -> tuple[Network, ...]:
        try:
            return self.allowed_networks() + parse_networks(self.priority_clients)
        except ValueError as err:
            raise ModbusServerError(f"priority_clients: {err}") from err


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


#: The server's live numbers: ModbusCounters' fields and the rest of ServerDiagnostics'
#: (made from both, so that it cannot miss one). Mutable: bumped per request (a new frozen
#: snapshot per request cost more than the request's own handling); `ModbusServer.counters`
#: hands out frozen copies, the register image reads it as its ServerDiagnostics.
_Tally = dataclasses.make_dataclass("_Tally", _tally_fields(), slots=True)


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
        self._priority_networks = config.priority_networks()
        self.identity = DeviceIdentity(device_name=config.device_name, map_version=MAP_VERSION)
        self._version = version_numbers(self.identity.version)
        major, minor, patch = self._version
        self._tally = _Tally(version_major=major, version_minor=minor, version_patch=patch,
                             device_name=config.device_name)
        # What a read of the input table answers: the newest snapshot's image with the
        # server's rows written over it (by _server_rows, only those that changed).
        self._image: list[int] = encode_input_registers(NOTHING_PUBLISHED, word_order=config.word_order)
        self._server_rows = ServerRowEncoder(config.word_order)
        self._server_rows.write(self._image, self._tally, all_rows=True)
        self._pending: ValuesSource | None = None
        self._device_context: SimDevice | None = None
        self._tcp: _TcpServer | None = None
        self._rtu: _SerialServer | None = None
        self._rtu_task: asyncio.Task[None] | None = None
        self._rtu_down = False
        self._handlers: set[_GatewayRequestHandler] = set()
        #: admitted TCP connections, in admission order
        self._connections: dict[int, _GatewayRequestHandler] = {}
        self.peer_log = PeerLogLimiter(log, config.peer_log_interval_s)
        self._sweeper: asyncio.TimerHandle | None = None
        self._restore_exception_handler: Callable[[], None] | None = None
        self._last_accept_error_s = -math.inf  # loop time of the last EMFILE on accept
        self._started = False

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
        t = self._tally
        return ModbusCounters(**{name: getattr(t, name) for name in _COUNTER_FIELDS})

    def input_registers(self, address: int, count: int) -> list[int] | ExcCodes:
        """The words a read of `count` input registers from `address` answers (Modbus
        function 04), or the exception code for a range outside the table.

        The newest snapshot (encoded here, on the first read after `update`) with the
        server's own rows as they are now; input reads never go through pymodbus's
        datastore (the hot request: its per-register checks and a copy of the whole
        table per read cost as much as the rest of the request).
        """
        if address < 0 or count < 1 or address + count > INPUT_SIZE:
            return ExcCodes.ILLEGAL_ADDRESS
        if self._before_read is not None:
            self._before_read()
        image = self._image
        if self._pending is not None:
            # the snapshot's rows only: the server's own are kept up to date below (each
            # read gets a slice, a copy: writing the image in place changes no answer given)
            write_value_rows(image, current(self._pending), self.config.word_order)
            self._pending = None
        self._server_rows.write(image, self._tally)
        words = image[address : address + count]
        if self._rtu_down and address <= _STATUS_ADDRESS < address + count:
            words[_STATUS_ADDRESS - address] |= int(StatusBits.MODBUS_RTU_DOWN)
        return words

    @property
    def tcp_port(self) -> int | None:
        """The bound TCP port (useful with port=0), None if TCP is not running."""
        if self._tcp is None or self._tcp.transport is None:
            return None
        sockets = getattr(self._tcp.transport, "sockets", None) or ()
        return sockets[0].getsockname()[1] if sockets else None

    @property
    def rtu_serving(self) -> bool:
        """True while the RTU port is open and served (False when RTU is off or down)."""
        return self._rtu is not None and not self._rtu_down

    async def start(self) -> None:
        """Listen on TCP and open the RTU port.

        Raises ModbusServerError with one line naming the cause when the TCP port cannot
        be listened on or the RTU port cannot take its settings. A missing RTU port is no
        error: the server starts without it, sets MODBUS_RTU_DOWN and keeps trying.
        """
        if self._started:
            raise ModbusServerError("server already started")
        self._started = True
        _PYMODBUS_LOG.addFilter(_PYMODBUS_DUPLICATES)  # one filter object: adding twice is a no-op
        self._device_context = self._device()
        cfg = self.config
        try:
            if cfg.tcp_enabled:
                await self._start_tcp()
            if cfg.rtu_enabled:
                problem = await asyncio.to_thread(self._probe_rtu)
                if problem is not None and not problem.missing:
                    raise ModbusServerError(problem.reason)
                if problem is None:
                    problem = await self._start_rtu()
                if problem is not None:
                    self._rtu_gone(problem.reason)
        except ModbusServerError:
            await self.stop()
            raise
        self._arm_sweep()
        log.info(
            "Modbus server started (tcp port %s, rtu %s)",
            self.tcp_port,
            cfg.rtu_port if cfg.rtu_enabled else "off",
        )

    async def stop(self) -> None:
        self._started = False
        if self._sweeper is not None:
            self._sweeper.cancel()
            self._sweeper = None
        task, self._rtu_task = self._rtu_task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        servers = [s for s in (self._tcp, self._rtu) if s is not None]
        self._tcp = self._rtu = None
        for server in servers:
            await server.shutdown()
        for handler in list(self._handlers):
            handler.cancel_pending()
        self._handlers.clear()
        self._connections.clear()
        if self._restore_exception_handler is not None:
            loop = asyncio.get_running_loop()
            if loop.time() - self._last_accept_error_s < _ACCEPT_RETRY_MARGIN_S:
                # not at once: the accept retry asyncio scheduled after EMFILE may still fire
                loop.call_later(_ACCEPT_RETRY_MARGIN_S, self._restore_exception_handler)
            else:
                self._restore_exception_handler()
            self._restore_exception_handler = None
        self.peer_log.flush(everything=True)  # the counts held back: said before the server goes

    # ------------------------------------------------------- start helpers --
    async def _start_tcp(self) -> None:
        cfg = self.config
        self._tcp = _TcpServer(self, context=self._device_context, address=(cfg.host, cfg.port))
        try:
            await self._tcp.serve_forever(background=True)
        except (RuntimeError, OSError) as err:
            # pymodbus says only "Could not start listen" (the cause in its own warning):
            # find the cause with a bind of our own
            self._tcp = None
            reason = await asyncio.to_thread(tcp_listen_problem, cfg.host, cfg.port)
            raise ModbusServerError(reason) from err
        self._install_accept_error_handler()

    def _probe_rtu(self) -> RtuPortProblem | None:
        cfg = self.config
        return probe_rtu_port(cfg.rtu_port, cfg.rtu_baudrate, cfg.rtu_parity, cfg.rtu_bytesize, cfg.rtu_stopbits)

    async def _start_rtu(self) -> RtuPortProblem | None:
        """Open the RTU port; a problem (it vanished since the probe) or None."""
        cfg = self.config
        rtu = _SerialServer(
            self,
            context=self._device_context,
            framer=FramerType.RTU,
            port=cfg.rtu_port,
            baudrate=cfg.rtu_baudrate,
            parity=cfg.rtu_parity,
            bytesize=cfg.rtu_bytesize,
            stopbits=cfg.rtu_stopbits,
        )
        try:
            await rtu.serve_forever(background=True)
        except (RuntimeError, OSError, termios.error) as err:  # it changed since the probe
            await rtu.shutdown()
            return RtuPortProblem(f"RTU port {cfg.rtu_port}: {err}", missing=True)
        self._rtu = rtu
        self._rtu_down = False
        return None

    def _rtu_gone(self, reason: str) -> None:
        """The RTU port is missing or was lost: flag it and reopen it with back-off."""
        self._rtu_down = True
        self._bump(rtu_open_failures=1)
        if self._rtu_task is None and self._started:
            self.peer_log.note("Modbus RTU", "rtu open",
                               f"{reason}; Modbus RTU down, retrying with back-off (status bit MODBUS_RTU_DOWN)")
            self._rtu_task = asyncio.get_running_loop().create_task(self._reopen_rtu(), name="modbus-rtu-reopen")

    async def _reopen_rtu(self) -> None:
        delay = RTU_RETRY_MIN_S
        try:
            if self._rtu is not None:  # lost while serving: close what is left of it
                rtu, self._rtu = self._rtu, None
                await rtu.shutdown()
            while True:
                await asyncio.sleep(delay)
                delay = min(2 * delay, RTU_RETRY_MAX_S)
                problem = await asyncio.to_thread(self._probe_rtu)
                if problem is None:
                    problem = await self._start_rtu()
                if problem is None:
                    log.info("Modbus RTU serving on %s again", self.config.rtu_port)
                    return
                self._bump(rtu_open_failures=1)
                self.peer_log.note("Modbus RTU", "rtu open", f"{problem.reason}; still retrying")
        finally:
            self._rtu_task = None

    def _install_accept_error_handler(self) -> None:
        """accept() failing for lack of file descriptors (EMFILE) makes asyncio log a
        traceback per attempt; here it is counted and logged once per interval.
        asyncio itself pauses accepting for a second each time."""
        loop = asyncio.get_running_loop()
        previous = loop.get_exception_handler()
        tcp = self._tcp
        listening = {sock.fileno() for sock in (getattr(tcp.transport, "sockets", None) or ())}

        def handler(loop: asyncio.AbstractEventLoop, context: dict) -> None:
            sock = context.get("socket")
            if context.get("message") == _ACCEPT_ERROR and sock is not None and sock.fileno() in listening:
                self._last_accept_error_s = loop.time()
                self._bump(accept_errors=1)
                self.peer_log.note("Modbus TCP listener", "accept error",
                                   f"cannot accept connections: {context.get('exception')}")
                return
            if _is_late_accept_retry(context):
                # asyncio retries accept() a second after EMFILE; a listener closed in
                # between makes that retry fail on its closed socket: nothing to report
                log.debug("accept retry after the listener closed: %s", context.get("exception"))
                return
            if previous is not None:
                previous(loop, context)
            else:
                loop.default_exception_handler(context)

        def restore() -> None:
            if loop.get_exception_handler() is handler:
                loop.set_exception_handler(previous)

        loop.set_exception_handler(handler)
        self._restore_exception_handler = restore

    # ---------------------------------------------------------- connections --
    def _admit(self, handler: _GatewayRequestHandler) -> bool:
        """Whether a new TCP connection may stay (closing another for it if need be)."""
        handler.priority = address_in(handler.peer_ip, self._priority_networks)
        others = [h.connection() for h in self._connections.values()]
        decision = admit(handler.priority, others, self.config.max_connections)
        if not decision.admitted:
            self._bump(refused_connections=1)
            self.peer_log.note(handler.peer_ip or "?", "refused",
                               f"Modbus connection refused: {self.config.max_connections} open (max_connections)")
            return False
        if decision.evict is not None:
            victim = self._connections.get(decision.evict)
            if victim is not None:
                self.peer_log.note(victim.peer_ip or "?", "evicted",
                                   f"Modbus connection {victim.source} closed at max_connections: it had done "
                                   f"least, room for {'priority ' if handler.priority else ''}client "
                                   f"{handler.peer_ip}")
                victim.close_connection(abort=True)
        self._connections[id(handler)] = handler
        return True

    def _arm_sweep(self) -> None:
        timeout = self.config.idle_timeout_s
        interval = min(SWEEP_INTERVAL_S, timeout / 4) if timeout > 0 else SWEEP_INTERVAL_S
        self._sweeper = asyncio.get_running_loop().call_later(interval, self._sweep)

    def _sweep(self) -> None:
        now = asyncio.get_running_loop().time()
        for key in idle([h.connection() for h in self._connections.values()], now, self.config.idle_timeout_s):
            handler = self._connections.get(key)
            if handler is not None:
                log.debug("Modbus connection %s idle for %.0f s: closing", handler.source, self.config.idle_timeout_s)
                handler.close_connection(abort=False)
        self.peer_log.flush()
        self._arm_sweep()

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

    def _bump(self, **deltas: int) -> None:
        t = self._tally
        for name, delta in deltas.items():
            setattr(t, name, getattr(t, name) + delta)

    def _refusal(self, function_code: int, handler: _GatewayRequestHandler) -> ExcCodes | None:
        """Why this request must not reach the datastore, or None."""
        if function_code not in SUPPORTED_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        if function_code not in WRITE_FUNCTIONS:
            return None
        if self.config.writes_enabled and (
            self.config.rtu_writes_enabled if handler.is_rtu else address_in(handler.peer_ip, self._networks)
        ):
            return None
        self._bump(rejected_writes=1)
        self.peer_log.note(handler.peer_ip or handler.source, "refused write",
                           f"Modbus write refused from {handler.source}")
        return ExcCodes.ILLEGAL_FUNCTION

    def _identification(self, pdu: ReadDeviceInformationRequest) -> ModbusPDU:
        objects = device_information(self.identity, pdu.read_code, pdu.object_id)
        if isinstance(objects, ExcCodes):
            return ExceptionResponse(pdu.function_code, objects)
        response = ReadDeviceInformationResponse(read_code=pdu.read_code, information=objects)
        response.conformity = CONFORMITY_LEVEL
        return response

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
        for the whole table (starting at address 0), `set_values` None for reads. Only
        the holding table comes here: input reads are answered by `input_registers`.
        """
        del function_code, start_address, count
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
        self._tally.command_counter += 1
        self._tally.command_result = result
        self._bump(
            commands_done=int(result is CommandResult.DONE),
            commands_declined=int(result is CommandResult.DECLINED),
            commands_failed=int(result is CommandResult.FAILED),
        )
        # a PLC writes the hint every cycle: one line per source, command and result and
        # peer_log_interval_s, with a count
        self.peer_log.note(source, f"command {command.name} {result.name}",
                           f"Modbus command {command.name}: {result.name}", logging.INFO)
        return result


class _InputRegistersResponse(ReadInputRegistersResponse):
    """pymodbus's response with the words packed in one call (its encode packs one
    register at a time, growing a bytes object: a measurable share of a 67-word read)."""

    def encode(self) -> bytes:
        count = len(self.registers)
        return struct.pack(f">B{count}H", 2 * count, *self.registers)


def _clear_registers(registers: list[int]) -> None:
    registers[0:HOLDING_SIZE] = [0] * HOLDING_SIZE


@dataclass(frozen=True, slots=True)
class _Undecodable:
    frame: bytes
    error: ModbusIOException


class _GatewayRequestHandler(ServerRequestHandler):
    """One per TCP connection (one for the serial line): framing, admission, order.

    Requests go into one queue per connection and one worker answers them in order
    (a write pipelined before a read is seen by that read).
    """

    server: _TcpServer | _SerialServer

    def __init__(self, owner: _TcpServer | _SerialServer) -> None:
        super().__init__(owner, owner.trace_packet, owner.trace_pdu, owner.trace_connect)
        self.gateway = owner.gateway
        self.is_rtu = owner.is_rtu
        self.peer_ip: str | None = None
        self.priority = False
        self.source = "modbus-rtu" if self.is_rtu else "modbus-tcp"
        self._admitted = False
        self._closing = False
        self._last_request_s = self.loop.time()
        self._requests = 0  # complete requests (modbus_admission.least_active)
        self._buffer = bytearray()
        self._queue: collections.deque[ModbusPDU | _Undecodable] = collections.deque()
        self._worker: asyncio.Task[None] | None = None
        self._pause_reasons: set[str] = set()
        self.gateway._handlers.add(self)

    # ------------------------------------------------------ connection life --
    def connection(self) -> Connection:
        return Connection(key=id(self), priority=self.priority, last_request_s=self._last_request_s,
                          requests=self._requests)

    def callback_connected(self) -> None:
        super().callback_connected()
        if self.is_rtu:
            self.source = f"modbus-rtu:{self.gateway.config.rtu_port}:unit{self.gateway.config.unit_id}"
            return
        peer = self.transport.get_extra_info("peername") if self.transport else None
        if peer:
            self.peer_ip = str(peer[0])
            self.source = f"modbus-tcp:{peer[0]}:{peer[1]}"
        if not self.gateway._admit(self):
            self._closing = True
            self.transport.abort()  # RST at once: the file descriptor is free again now
            return
        self._admitted = True
        self.gateway._bump(clients_connected=1, connections_total=1)

    def callback_disconnected(self, exc: Exception | None) -> None:
        super().callback_disconnected(exc)
        if self._admitted:
            self._admitted = False
            self.gateway._bump(clients_connected=-1)
            self.gateway._connections.pop(id(self), None)
        self.cancel_pending()
        self.gateway._handlers.discard(self)
        if self.is_rtu and exc is not None:  # the serial port went away under us
            self.gateway._rtu_gone(f"RTU port {self.gateway.config.rtu_port} lost: {exc}")

    def close_connection(self, abort: bool) -> None:
        """Close this TCP connection: `abort` resets it at once (a bad peer), else the
        answers already written go out first (idle timeout)."""
        if self._closing or self.transport is None:
            return
        self._closing = True
        self.gateway._bump(closed_connections=1)
        # no longer counts against max_connections, though its disconnect comes later
        self.gateway._connections.pop(id(self), None)
        if abort:
            self.transport.abort()
        else:
            self.transport.close()

    def cancel_pending(self) -> None:
        self._queue.clear()
        if self._worker is not None:
            self._worker.cancel()
            self._worker = None

    # asyncio flow control: a client that does not read its answers stops being read
    def pause_writing(self) -> None:
        self._pause("writes", True)

    def resume_writing(self) -> None:
        self._pause("writes", False)

    def _pause(self, reason: str, on: bool) -> None:
        was_paused = bool(self._pause_reasons)
        if on:
            self._pause_reasons.add(reason)
        else:
            self._pause_reasons.discard(reason)
        if self.transport is None or self._closing or was_paused == bool(self._pause_reasons):
            return
        if self._pause_reasons:
            self.transport.pause_reading()
        else:
            self.transport.resume_reading()

    # -------------------------------------------------------------- framing --
    def data_received(self, data: bytes) -> None:
        """TCP: split the stream into MBAP frames here (pymodbus's framer waits forever
        on a bad header and drops its buffer past 264 bytes); RTU: pymodbus's framing,
        which resynchronises on the CRC."""
        if self.is_rtu:
            super().data_received(data)
            return
        if self._closing:
            return
        self._buffer += data
        self._take_frames()

    def _take_frames(self) -> None:
        buffer = self._buffer
        start = 0  # frames are cut by offset and the buffer compacted once: a 256 KiB read
        # of pipelined requests must not cost a memmove per frame
        while len(self._queue) < MAX_QUEUED_REQUESTS and len(buffer) - start >= MBAP_HEADER_BYTES:
            _, protocol_id, length = struct.unpack_from(">HHH", buffer, start)
            if protocol_id != 0 or not MBAP_LENGTH_MIN <= length <= MBAP_LENGTH_MAX:
                self._reject_stream(f"bad MBAP header (protocol id {protocol_id}, length {length})")
                return
            end = start + 6 + length
            if len(buffer) < end:
                break
            frame = bytes(buffer[start:end])
            start = end
            self._last_request_s = self.loop.time()
            self._requests += 1
            try:
                _, pdu = self.framer.handleFrame(frame, 0, 0)
            except ModbusIOException as exc:
                self._enqueue(_Undecodable(frame, exc))
                continue
            if pdu is not None:
                self._enqueue(pdu)
        del buffer[:start]
        self._pause("queue", len(self._queue) >= MAX_QUEUED_REQUESTS)

    def _reject_stream(self, why: str) -> None:
        # No resynchronisation is possible on a byte stream without frame markers:
        # whatever follows would be read at the wrong offsets. Close at once.
        self.gateway._bump(rejected_frames=1)
        self.gateway.peer_log.note(self.peer_ip or self.source, "bad frame",
                                   f"Modbus connection {self.source} closed: {why}")
        self._buffer.clear()
        self.close_connection(abort=True)

    def callback_data(self, data: bytes, addr: tuple | None = None) -> int:
        """RTU only (TCP frames in data_received): decode every complete request in
        `data` and queue each with its PDU bound.

        Replaces ServerRequestHandler.callback_data, which handles one request per
        call and lets the scheduled task re-read `last_pdu` later (a newer request
        could replace the one that was checked).
        """
        used_total = 0
        while used_total < len(data):
            chunk = data[used_total:]
            try:
                used = TransactionManager.callback_data(self, chunk, addr)
            except ModbusIOException as exc:
                self._enqueue(_Undecodable(chunk, exc))
                return len(data)
            if self.last_pdu is not None:
                self._enqueue(self.last_pdu)
                self.last_pdu = None
            if not used:
                break  # incomplete frame: wait for more bytes
            used_total += used
        return used_total

    def handle_later(self) -> None:  # pragma: no cover - requests are queued directly
        raise RuntimeError("handle_later is not used by the gateway handler")

    async def handle_request(self) -> None:  # pragma: no cover - see _work
        raise RuntimeError("handle_request is not used by the gateway handler")

    # ------------------------------------------------------------- answering --
    def _enqueue(self, item: ModbusPDU | _Undecodable) -> None:
        self._queue.append(item)
        if self._worker is None:
            self._worker = self.loop.create_task(self._work())

    async def _work(self) -> None:
        try:
            while self._queue:
                item = self._queue.popleft()
                try:
                    if isinstance(item, _Undecodable):
                        self._answer_undecodable(item.frame, item.error)
                    else:
                        await self._handle(item)
                except Exception:  # a bug answering one request must not stall the rest
                    log.exception("Modbus request from %s failed", self.source)
                if "queue" in self._pause_reasons and len(self._queue) < MAX_QUEUED_REQUESTS // 2:
                    self._take_frames()  # caught up: read the frames held back, resume reading
        finally:
            self._worker = None

    def _answer_undecodable(self, frame: bytes, exc: ModbusIOException) -> None:
        # pymodbus answers these with function code 0x80; answer with the request's own
        # function code as the Modbus spec wants: 01 for a function we do not serve, 03
        # for a known function whose quantity/byte count/length is wrong.
        _, _, _, pdu_bytes = self.framer.decode(frame)
        function_code = pdu_bytes[0] & 0x7F if pdu_bytes else 0
        code = ExcCodes.ILLEGAL_VALUE if function_code in SUPPORTED_FUNCTIONS else ExcCodes.ILLEGAL_FUNCTION
        dev_id = exc.dev_id if exc.dev_id is not None else 0
        if self.is_rtu and dev_id != self.gateway.config.unit_id:
            return  # for another device on the line
        self.gateway._bump(requests=1, rejected_frames=1)
        self.gateway.peer_log.note(self.peer_ip or self.source, "undecodable",
                                   f"undecodable Modbus request (function {function_code}) from {self.source}")
        response = ExceptionResponse(function_code, code, device_id=dev_id, transaction=exc.transaction_id or 0)
        self.server_send(response, None)

    async def _handle(self, pdu: ModbusPDU) -> None:
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # addressed to another device on the line (or broadcast): stay silent
        self.gateway._bump(requests=1)
        refusal = self.gateway._refusal(pdu.function_code, self)
        if refusal is not None:
            response: ModbusPDU = ExceptionResponse(pdu.function_code, refusal)
        elif pdu.function_code == READ_INPUT:
            response = self._read_input(pdu)
        elif pdu.function_code == ENCAPSULATED_INTERFACE:
            if isinstance(pdu, ReadDeviceInformationRequest):
                response = self.gateway._identification(pdu)
            else:  # another MEI type (e.g. 13, CANopen): not served
                response = ExceptionResponse(pdu.function_code, ExcCodes.ILLEGAL_FUNCTION)
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
        self.server_send(response, None)

    def _read_input(self, pdu: ModbusPDU) -> ModbusPDU:
        try:
            words = self.gateway.input_registers(pdu.address, pdu.count)
        except Exception as exc:  # a bug encoding the image answers 04, the server lives on
            log.error("Modbus request %s failed: %s\n%s", pdu, exc, traceback.format_exc())
            return ExceptionResponse(pdu.function_code, ExcCodes.DEVICE_FAILURE)
        if isinstance(words, ExcCodes):
            return ExceptionResponse(pdu.function_code, words)
        return _InputRegistersResponse(registers=words)

    def server_send(self, pdu: ModbusPDU | None, addr: tuple | None) -> None:
        if pdu is None or self._closing or self.transport is None:
            return
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # e.g. pymodbus's answer to an undecodable frame for another device
        if isinstance(pdu, ExceptionResponse):
            self.gateway._bump(exceptions=1)
        super().server_send(pdu, addr)


class _GatewayServer:
    """What the TCP and the RTU server add to pymodbus' own: the gateway they serve and
    its request handler for every connection (mixed in before the pymodbus class)."""

    is_rtu = False

    def __init__(self, gateway: ModbusServer, **kwargs: object) -> None:
        self.gateway = gateway
        super().__init__(**kwargs)  # type: ignore[call-arg]

    def callback_new_connection(self) -> _GatewayRequestHandler:
        return _GatewayRequestHandler(self)


class _TcpServer(_GatewayServer, ModbusTcpServer):
    is_rtu = False


class _SerialServer(_GatewayServer, ModbusSerialServer):
    is_rtu = True
