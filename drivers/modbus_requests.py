"""Modbus request handling: one handler per TCP connection (one for the RTU line).

It cuts the TCP stream into MBAP frames (drivers/modbus_framing.py) before pymodbus sees
them, asks the connection table whether the peer may stay (drivers/modbus_admission.py),
decides per request who may write (pymodbus gives the datastore no client address, but
each TCP connection has its own handler whose transport knows the peer — pymodbus issue
#2159 has the same question; no public hook exists in 3.x), and answers the requests of a
connection in the order they arrived, however many come in one segment: past
MAX_QUEUED_REQUESTS waiting, it stops reading that connection until it has caught up (and
stops reading a client that does not read its answers), so memory stays bounded and
nothing is dropped. Input reads are answered from the server's image; writes and holding
reads go through the datastore (drivers/modbus_datastore.py); device identification
(function 43 / MEI 14) from the server's `DeviceIdentity`.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import struct
import traceback
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.mei_message import ReadDeviceInformationRequest, ReadDeviceInformationResponse
from pymodbus.pdu.register_message import ReadInputRegistersResponse
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.transaction import TransactionManager

from .modbus_admission import Connection, ConnectionTable, Network, address_in
from .modbus_datastore import REQUEST_SOURCE, ServerTally
from .modbus_framing import BadMbapHeader, mbap_frame_end
from .modbus_identity import CONFORMITY_LEVEL, DeviceIdentity, device_information
from .peer_log import PeerLogLimiter

if TYPE_CHECKING:
    from .modbus_server import ModbusServerConfig

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

#: Requests of one connection waiting for their answer; beyond, the server stops reading
#: that connection until it caught up (TCP flow control pushes back on the client).
MAX_QUEUED_REQUESTS = 32


class HandlerHost(Protocol):
    """What a request handler uses of the server it serves (`ModbusServer`)."""

    config: ModbusServerConfig
    identity: DeviceIdentity
    peer_log: PeerLogLimiter
    tally: ServerTally
    connections: ConnectionTable
    #: every live handler (TCP connections and the RTU line), so a stop can cancel them
    handlers: set[GatewayRequestHandler]
    write_networks: tuple[Network, ...]

    def input_registers(self, address: int, count: int) -> list[int] | ExcCodes: ...

    def rtu_lost(self, reason: str) -> None: ...


def identification(identity: DeviceIdentity, pdu: ReadDeviceInformationRequest) -> ModbusPDU:
    """The answer to a read device identification request (function 43 / MEI 14)."""
    objects = device_information(identity, pdu.read_code, pdu.object_id)
    if isinstance(objects, ExcCodes):
        return ExceptionResponse(pdu.function_code, objects)
    response = ReadDeviceInformationResponse(read_code=pdu.read_code, information=objects)
    response.conformity = CONFORMITY_LEVEL
    return response


class InputRegistersResponse(ReadInputRegistersResponse):
    """pymodbus's response with the words packed in one call (its encode packs one
    register at a time, growing a bytes object: a measurable share of a 67-word read)."""

    def encode(self) -> bytes:
        count = len(self.registers)
        return struct.pack(f">B{count}H", 2 * count, *self.registers)


@dataclass(frozen=True, slots=True)
class _Undecodable:
    frame: bytes
    error: ModbusIOException


class GatewayRequestHandler(ServerRequestHandler):
    """One per TCP connection (one for the serial line): framing, admission, order.

    Requests go into one queue per connection and one worker answers them in order
    (a write pipelined before a read is seen by that read).
    """

    server: TcpServer | SerialServer

    def __init__(self, owner: TcpServer | SerialServer) -> None:
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
        self.gateway.handlers.add(self)

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
        if not self.gateway.connections.admit(self):
            self._closing = True
            self.transport.abort()  # RST at once: the file descriptor is free again now
            return
        self._admitted = True
        self.gateway.tally.bump(clients_connected=1, connections_total=1)

    def callback_disconnected(self, exc: Exception | None) -> None:
        super().callback_disconnected(exc)
        if self._admitted:
            self._admitted = False
            self.gateway.tally.bump(clients_connected=-1)
            self.gateway.connections.release(self)
        self.cancel_pending()
        self.gateway.handlers.discard(self)
        if self.is_rtu and exc is not None:  # the serial port went away under us
            self.gateway.rtu_lost(f"RTU port {self.gateway.config.rtu_port} lost: {exc}")

    def close_connection(self, abort: bool) -> None:
        """Close this TCP connection: `abort` resets it at once (a bad peer), else the
        answers already written go out first (idle timeout)."""
        if self._closing or self.transport is None:
            return
        self._closing = True
        self.gateway.tally.bump(closed_connections=1)
        # no longer counts against max_connections, though its disconnect comes later
        self.gateway.connections.release(self)
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
        while len(self._queue) < MAX_QUEUED_REQUESTS:
            try:
                end = mbap_frame_end(buffer, start)
            except BadMbapHeader as bad:
                self._reject_stream(str(bad))
                return
            if end is None:
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
        self.gateway.tally.bump(rejected_frames=1)
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
        self.gateway.tally.bump(requests=1, rejected_frames=1)
        self.gateway.peer_log.note(self.peer_ip or self.source, "undecodable",
                                   f"undecodable Modbus request (function {function_code}) from {self.source}")
        response = ExceptionResponse(function_code, code, device_id=dev_id, transaction=exc.transaction_id or 0)
        self.server_send(response, None)

    async def _handle(self, pdu: ModbusPDU) -> None:
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # addressed to another device on the line (or broadcast): stay silent
        self.gateway.tally.bump(requests=1)
        refusal = self._refusal(pdu.function_code)
        if refusal is not None:
            response: ModbusPDU = ExceptionResponse(pdu.function_code, refusal)
        elif pdu.function_code == READ_INPUT:
            response = self._read_input(pdu)
        elif pdu.function_code == ENCAPSULATED_INTERFACE:
            if isinstance(pdu, ReadDeviceInformationRequest):
                response = identification(self.gateway.identity, pdu)
            else:  # another MEI type (e.g. 13, CANopen): not served
                response = ExceptionResponse(pdu.function_code, ExcCodes.ILLEGAL_FUNCTION)
        else:
            source_token = REQUEST_SOURCE.set(self.source)
            try:
                response = await pdu.datastore_update(self.server.context, pdu.dev_id)
            except Exception as exc:  # a datastore bug answers 04, the server lives on
                log.error("Modbus request %s failed: %s\n%s", pdu, exc, traceback.format_exc())
                response = ExceptionResponse(pdu.function_code, ExcCodes.DEVICE_FAILURE)
            finally:
                REQUEST_SOURCE.reset(source_token)
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
        return InputRegistersResponse(registers=words)

    def _refusal(self, function_code: int) -> ExcCodes | None:
        """Why this request must not reach the datastore, or None."""
        if function_code not in SUPPORTED_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        if function_code not in WRITE_FUNCTIONS:
            return None
        config = self.gateway.config
        if config.writes_enabled and (
            config.rtu_writes_enabled if self.is_rtu else address_in(self.peer_ip, self.gateway.write_networks)
        ):
            return None
        self.gateway.tally.bump(rejected_writes=1)
        self.gateway.peer_log.note(self.peer_ip or self.source, "refused write",
                                   f"Modbus write refused from {self.source}")
        return ExcCodes.ILLEGAL_FUNCTION

    def server_send(self, pdu: ModbusPDU | None, addr: tuple | None) -> None:
        if pdu is None or self._closing or self.transport is None:
            return
        if self.is_rtu and pdu.dev_id != self.gateway.config.unit_id:
            return  # e.g. pymodbus's answer to an undecodable frame for another device
        if isinstance(pdu, ExceptionResponse):
            self.gateway.tally.bump(exceptions=1)
        super().server_send(pdu, addr)


class GatewayServer:
    """What the TCP and the RTU server add to pymodbus' own: the gateway they serve and
    its request handler for every connection (mixed in before the pymodbus class)."""

    is_rtu = False

    def __init__(self, gateway: HandlerHost, **kwargs: object) -> None:
        self.gateway = gateway
        super().__init__(**kwargs)  # type: ignore[call-arg]

    def callback_new_connection(self) -> GatewayRequestHandler:
        return GatewayRequestHandler(self)


class TcpServer(GatewayServer, ModbusTcpServer):
    is_rtu = False


class SerialServer(GatewayServer, ModbusSerialServer):
    is_rtu = True
