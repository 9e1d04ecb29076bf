"""Modbus TCP server and optional Modbus RTU server publishing `PublishedValues`.

Built on pymodbus 3.16's server classes. This module is the server's public API
(`ModbusServer`, `ModbusServerConfig`, `ModbusServerError`) and its life: start, stop, the
RTU port's loss and reopening, accept() failures, the idle sweep. Its parts:
- drivers/modbus_datastore.py: what the registers hold — the input image (both servers,
  TCP and RTU, read the same one, encoded whole from the newest snapshot, so a client never
  sees half of an old and half of a new 32-bit value), the command registers, the counters;
- drivers/modbus_requests.py: one handler per connection — MBAP framing
  (drivers/modbus_framing.py), who may write, answers in arrival order, bounded queues;
- drivers/modbus_admission.py: which TCP connections it keeps, so a PLC is never locked
  out and a bad peer costs bounded resources: at most `max_connections`; at the limit a
  newcomer gets in by closing the connection that has done least, never a priority client
  (write_allow and priority_clients) for a non-priority one; idle connections are closed
  after `idle_timeout_s`;
- drivers/modbus_identity.py: device identification (function 43 / MEI 14, read codes 1–4);
- drivers/peer_log.py: what peers do wrong is logged at most once per peer and interval.

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
import logging
import math
import termios
from collections.abc import Callable
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType

from .modbus_admission import ConnectionTable, Network, parse_networks
from .modbus_datastore import CommandRegisters, InputImage, ModbusCounters, ServerTally
from .modbus_identity import DeviceIdentity, version_numbers
from .modbus_map import BY_NAME, MAP_VERSION, WordOrder, string32_complaint
from .modbus_ports import RtuPortProblem, probe_rtu_port, tcp_listen_problem
from .modbus_requests import GatewayRequestHandler, SerialServer, TcpServer
from .peer_log import PeerLogLimiter
from .published_values import CommandCallback, StatusBits, ValuesSource

log = logging.getLogger(__name__)

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
        # called before each read of the input registers: the daemon takes the bytes
        # the board sent since its last wakeup (and calls update() if there were any)
        self._before_read = before_read
        self.write_networks: tuple[Network, ...] = config.allowed_networks()
        self.identity = DeviceIdentity(device_name=config.device_name, map_version=MAP_VERSION)
        major, minor, patch = version_numbers(self.identity.version)
        #: the live counters (ModbusCounters' and ServerDiagnostics' fields), bumped by the handlers
        self.tally = ServerTally(version_major=major, version_minor=minor, version_patch=patch,
                                 device_name=config.device_name)
        self.peer_log = PeerLogLimiter(log, config.peer_log_interval_s)
        self._image = InputImage(config.word_order, self.tally)
        self._commands = CommandRegisters(on_command, self.tally, self.peer_log)
        self._tcp: TcpServer | None = None
        self._rtu: SerialServer | None = None
        self._rtu_task: asyncio.Task[None] | None = None
        self._rtu_down = False
        #: every live request handler (TCP connections and the RTU line)
        self.handlers: set[GatewayRequestHandler] = set()
        #: the admitted TCP connections
        self.connections = ConnectionTable(config.max_connections, config.priority_networks(),
                                           config.idle_timeout_s, self.peer_log, self.tally.bump)
        self._sweeper: asyncio.TimerHandle | None = None
        self._restore_exception_handler: Callable[[], None] | None = None
        self._last_accept_error_s = -math.inf  # loop time of the last EMFILE on accept
        self._started = False

    # ---------------------------------------------------------------- API --
    def update(self, values: ValuesSource) -> None:
        """Publish a new snapshot (or a function returning it); the next read of any
        client sees all of it."""
        # Encoding (and, for a function, building the snapshot) is deferred to the next
        # read (drivers/modbus_datastore.py).
        self._image.update(values)

    @property
    def counters(self) -> ModbusCounters:
        return self.tally.snapshot()

    def input_registers(self, address: int, count: int) -> list[int] | ExcCodes:
        """The words a read of `count` input registers from `address` answers (Modbus
        function 04), or the exception code for a range outside the table.

        The newest snapshot (encoded here, on the first read after `update`) with the
        server's own rows as they are now; input reads never go through pymodbus's
        datastore (the hot request: its per-register checks and a copy of the whole
        table per read cost as much as the rest of the request).
        """
        if not InputImage.holds(address, count):
            return ExcCodes.ILLEGAL_ADDRESS
        if self._before_read is not None:
            self._before_read()
        words = self._image.words(address, count)
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
        self._device_context = self._commands.device()
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
                    self.rtu_lost(problem.reason)
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
        for handler in list(self.handlers):
            handler.cancel_pending()
        self.handlers.clear()
        self.connections.clear()
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
        self._tcp = TcpServer(self, context=self._device_context, address=(cfg.host, cfg.port))
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
        rtu = SerialServer(
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

    def rtu_lost(self, reason: str) -> None:
        """The RTU port is missing or was lost: flag it and reopen it with back-off."""
        self._rtu_down = True
        self.tally.bump(rtu_open_failures=1)
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
                self.tally.bump(rtu_open_failures=1)
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
                self.tally.bump(accept_errors=1)
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
    def _arm_sweep(self) -> None:
        timeout = self.config.idle_timeout_s
        interval = min(SWEEP_INTERVAL_S, timeout / 4) if timeout > 0 else SWEEP_INTERVAL_S
        self._sweeper = asyncio.get_running_loop().call_later(interval, self._sweep)

    def _sweep(self) -> None:
        self.connections.close_idle(asyncio.get_running_loop().time())
        self.peer_log.flush()
        self._arm_sweep()
