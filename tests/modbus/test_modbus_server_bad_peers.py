"""The Modbus TCP server against bad peers: connection limits with priority clients, idle
and slowloris connections, malformed headers, pipelining, clients that never read, log
volume, and accept() failing for lack of file descriptors (all on 127.0.0.1)."""
from __future__ import annotations

import asyncio
import logging
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.modbus_map import BY_NAME, MAP_VERSION, WordOrder
from drivers.modbus_requests import MAX_QUEUED_REQUESTS
from drivers.modbus_server import ModbusServer, ModbusServerConfig, ModbusServerError
from tests.modbus_helpers import SAMPLE, decode, mbap, read_table, serving, tcp_client, tcp_config
from tests.wire_helpers import Recorder, run

REPO = Path(__file__).resolve().parents[2]
PLC_IP = "127.0.0.2"  # the whole of 127/8 is loopback on Linux: a second client address
READ_VERSION = b"\x04\x00\x00\x00\x01"  # FC04, address 0 (MAP_VERSION), one register


def answer_to_version_read(transaction: int) -> bytes:
    return mbap(transaction, b"\x04\x02" + struct.pack(">H", MAP_VERSION))


async def open_raw(port: int, source_ip: str = "127.0.0.1") -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port, local_addr=(source_ip, 0))


async def closed_by_server(reader: asyncio.StreamReader, within_s: float) -> bool:
    """True when the server closes (EOF or reset) within `within_s`; answers are skipped."""
    deadline = time.monotonic() + within_s
    try:
        while time.monotonic() < deadline:
            data = await asyncio.wait_for(reader.read(4096), max(0.01, deadline - time.monotonic()))
            if not data:
                return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except TimeoutError:
        return False
    return False


async def wait_for(condition, within_s: float = 5.0) -> None:
    deadline = time.monotonic() + within_s
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        await asyncio.sleep(0.01)


# --------------------------------------------------------------------------- #
# Connection limit and priority clients
# --------------------------------------------------------------------------- #
def test_at_the_limit_a_newcomer_gets_in_and_a_priority_client_is_never_closed_for_it() -> None:
    """No peer holds the gateway: trickling clients and an idle flood are closed for a
    newcomer (the connection that has done least first); the PLC polling all along stays."""
    async def scenario() -> None:
        config = tcp_config(max_connections=4, write_allow=(PLC_IP,), idle_timeout_s=0)
        async with serving(config) as server:
            port = server.tcp_port
            async with tcp_client(port, source_ip=PLC_IP) as plc:
                assert not (await plc.read_input_registers(0, count=1, device_id=1)).isError()
                # three slowloris-like clients: one complete request each, then nothing
                slow = []
                for k in range(3):
                    reader, writer = await open_raw(port)
                    writer.write(mbap(k + 1, READ_VERSION))
                    assert await reader.readexactly(11) == answer_to_version_read(k + 1)
                    slow.append((reader, writer))
                # an idle flood: each newcomer gets in, closing the one that has done least
                flood = [await open_raw(port) for _ in range(10)]
                await wait_for(lambda: server.counters.closed_connections == 10)
                assert server.counters.refused_connections == 0 and server.counters.clients_connected == 4
                # the first of the flood closed the trickling client idle longest; after that the
                # flood's own connections, which never completed a request, went first
                assert await closed_by_server(slow[0][0], 1.0)
                assert not await closed_by_server(slow[1][0], 0.1)
                # a new ordinary client is answered; the PLC, polling all along, still is
                async with tcp_client(port) as newcomer:
                    assert not (await newcomer.read_input_registers(0, count=1, device_id=1)).isError()
                words = await read_table(plc)
                assert decode(plc, words, "POSITION", WordOrder.ABCD) == pytest.approx(SAMPLE.position_m, rel=1e-6)
                assert decode(plc, words, "MODBUS_CLOSED_CONNECTIONS", WordOrder.ABCD) == 11
                for _, writer in slow + flood:
                    writer.close()

    run(scenario())


def test_where_only_priority_clients_are_left_anyone_else_is_refused() -> None:
    async def scenario() -> None:
        config = tcp_config(max_connections=1, write_allow=(PLC_IP,), idle_timeout_s=0)
        async with serving(config) as server, tcp_client(server.tcp_port, source_ip=PLC_IP) as plc:
            reader, writer = await open_raw(server.tcp_port)
            assert await closed_by_server(reader, 1.0)
            assert server.counters.refused_connections == 1
            assert not (await plc.read_input_registers(0, count=1, device_id=1)).isError()
            writer.close()

    run(scenario())


def test_priority_clients_list_admits_without_write_rights() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        config = tcp_config(max_connections=2, write_allow=(), priority_clients=(PLC_IP,), writes_enabled=True)
        async with serving(config, recorder) as server:
            flood = [await open_raw(server.tcp_port) for _ in range(2)]
            async with tcp_client(server.tcp_port, source_ip=PLC_IP) as plc:
                assert not (await plc.read_input_registers(0, count=1, device_id=1)).isError()
                refused = await plc.write_register(0, 1, device_id=1)
                assert refused.isError() and refused.exception_code == 1  # priority is not write access
            for _, writer in flood:
                writer.close()

    run(scenario())
    assert recorder.calls == []


# --------------------------------------------------------------------------- #
# Idle and slowloris
# --------------------------------------------------------------------------- #
def test_idle_and_slowloris_connections_are_closed_polling_ones_are_not() -> None:
    async def scenario() -> None:
        async with serving(tcp_config(idle_timeout_s=0.4)) as server:
            port = server.tcp_port
            idle_reader, idle_writer = await open_raw(port)
            slow_reader, slow_writer = await open_raw(port)
            # slowloris: a header announcing 253 bytes, then one byte every 50 ms
            slow_writer.write(struct.pack(">HHHB", 1, 0, 254, 1))
            async with tcp_client(port) as poller:
                started = time.monotonic()
                while time.monotonic() - started < 1.2:
                    slow_writer.write(b"\x00")
                    assert not (await poller.read_input_registers(0, count=1, device_id=1)).isError()
                    await asyncio.sleep(0.05)
                assert await closed_by_server(idle_reader, 0.1)
                assert await closed_by_server(slow_reader, 0.1)
                assert server.counters.closed_connections == 2
                assert server.counters.clients_connected == 1  # the poller
            idle_writer.close()
            slow_writer.close()

    run(scenario())


# --------------------------------------------------------------------------- #
# Malformed frames: closed at once, never deaf
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "header",
    [
        struct.pack(">HHHB", 1, 5, 6, 1),  # protocol id 5
        struct.pack(">HHHB", 1, 0, 0, 1),  # length 0
        struct.pack(">HHHB", 1, 0, 1, 1),  # length 1: a unit id, no function code
        struct.pack(">HHHB", 1, 0, 255, 1),  # longer than any Modbus PDU
        struct.pack(">HHHB", 1, 0, 0xFFFF, 1),
    ],
)
def test_a_bad_header_closes_the_connection_at_once(header: bytes) -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            reader, writer = await open_raw(server.tcp_port)
            # the bad frame, then valid requests: before, the valid ones went unanswered
            # on a connection that stayed open
            writer.write(header + READ_VERSION + mbap(2, READ_VERSION) + mbap(3, READ_VERSION))
            assert await closed_by_server(reader, 1.0)
            writer.close()
            assert server.counters.rejected_frames == 1
            assert server.counters.closed_connections == 1
            async with tcp_client(server.tcp_port) as other:  # the server itself is fine
                assert not (await other.read_input_registers(0, count=1, device_id=1)).isError()

    run(scenario())


def test_an_undecodable_request_is_answered_and_the_next_ones_too() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            reader, writer = await open_raw(server.tcp_port)
            stream = mbap(1, b"\x04\x00") + b"".join(mbap(t, READ_VERSION) for t in range(2, 30))
            writer.write(stream)
            expected = mbap(1, b"\x84\x03") + b"".join(answer_to_version_read(t) for t in range(2, 30))
            got = await asyncio.wait_for(reader.readexactly(len(expected)), 5)
            assert got == expected
            assert server.counters.rejected_frames == 1
            writer.close()

    run(scenario())


# --------------------------------------------------------------------------- #
# Pipelining and flow control
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("count", [2, 23, MAX_QUEUED_REQUESTS + 1, 500])
def test_pipelined_requests_in_one_segment_are_all_answered_in_order(count: int) -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            reader, writer = await open_raw(server.tcp_port)
            writer.write(b"".join(mbap(t, READ_VERSION) for t in range(count)))
            expected = b"".join(answer_to_version_read(t) for t in range(count))
            got = await asyncio.wait_for(reader.readexactly(len(expected)), 10)
            assert got == expected
            assert server.counters.requests == count
            writer.close()

    run(scenario())


def test_a_pipelined_write_is_seen_by_the_read_after_it() -> None:
    async def scenario() -> None:
        tared = []

        def on_command(command, source):
            tared.append(command)
            server.update(SAMPLE.__class__(position_m=0.0))
            return True

        async with serving(tcp_config(writes_enabled=True), on_command) as server:
            reader, writer = await open_raw(server.tcp_port)
            position = BY_NAME["POSITION"].address
            writer.write(mbap(1, b"\x06\x00\x00\x00\x01") + mbap(2, struct.pack(">BHH", 4, position, 2)))
            first = await asyncio.wait_for(reader.readexactly(12), 5)
            second = await asyncio.wait_for(reader.readexactly(13), 5)
            assert first == mbap(1, b"\x06\x00\x00\x00\x01")
            assert second == mbap(2, b"\x04\x04" + struct.pack(">f", 0.0))
            writer.close()

    run(scenario())


def test_a_client_that_never_reads_costs_bounded_memory_and_others_are_served() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            hog = socket.create_connection(("127.0.0.1", server.tcp_port))
            hog.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            hog.setblocking(False)
            chunk = b"".join(mbap(t, READ_VERSION) for t in range(1000))
            sent = 0
            while sent < 64 * 2**20:  # until the kernel buffers are full (bounded either way)
                try:
                    sent += hog.send(chunk)
                except BlockingIOError:
                    break
                await asyncio.sleep(0)
            # wait until the server stopped answering (its queue done, its reading paused)
            answered = -1
            while answered != server.counters.requests:
                answered = server.counters.requests
                await asyncio.sleep(0.3)
            # requests it did not read wait in the kernel, not in the server's memory;
            # a server that kept reading would have answered everything that was sent
            assert sent - 12 * answered > 64 * 1024, (sent, answered)
            async with tcp_client(server.tcp_port) as other:
                assert not (await other.read_input_registers(0, count=1, device_id=1)).isError()
            hog.close()

    run(scenario(), timeout_s=120)


# --------------------------------------------------------------------------- #
# Log volume
# --------------------------------------------------------------------------- #
def test_peer_errors_are_logged_once_per_interval_with_a_count(caplog) -> None:
    async def scenario() -> None:
        async with serving(tcp_config(write_allow=(), writes_enabled=True, peer_log_interval_s=60)) as server:
            async with tcp_client(server.tcp_port) as client:
                for _ in range(200):
                    assert (await client.write_register(0, 1, device_id=1)).isError()
            for _ in range(50):  # a bad frame each, on a new connection each
                reader, writer = await open_raw(server.tcp_port)
                writer.write(struct.pack(">HHHB", 1, 7, 6, 1) + READ_VERSION)
                assert await closed_by_server(reader, 1.0)
                writer.close()
            assert server.counters.rejected_writes == 200
            assert server.counters.rejected_frames == 50
        async with serving(tcp_config(max_connections=1, write_allow=(), priority_clients=(PLC_IP,),
                                      peer_log_interval_s=60)) as server:
            _, holder = await open_raw(server.tcp_port, PLC_IP)
            for _ in range(50):  # at the limit, only a priority client left: refused
                reader, writer = await open_raw(server.tcp_port)
                assert await closed_by_server(reader, 1.0)
                writer.close()
            assert server.counters.refused_connections == 50
            holder.close()

    with caplog.at_level(logging.DEBUG):
        run(scenario())
    lines = [r for r in caplog.records if r.levelno >= logging.WARNING]
    # one line per (peer, kind) for a 60 s interval and one with its count when the server
    # stops, plus nothing from pymodbus
    assert len(lines) <= 6, [r.getMessage() for r in lines]
    assert sum(len(r.getMessage()) for r in lines) < 1200


def test_a_hint_written_every_cycle_is_logged_once_per_interval(caplog) -> None:
    """A PLC writes CMD_HINT_AT_REST every cycle, as the register map says: one line, not one per write."""

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True, peer_log_interval_s=60), Recorder()) as server:
            async with tcp_client(server.tcp_port) as plc:
                for _ in range(50):
                    assert not (await plc.write_register(BY_NAME["CMD_HINT_AT_REST"].address, 1,
                                                         device_id=1)).isError()
            assert server.counters.commands_done == 50

    with caplog.at_level(logging.INFO, logger="drivers.modbus_server"):
        run(scenario())
    lines = [r.getMessage() for r in caplog.records if "HINT_AT_REST" in r.getMessage()]
    # the first at once, the 49 others counted in one line when the server stops
    assert len(lines) == 2 and "49 times" in lines[1], lines


# --------------------------------------------------------------------------- #
# accept() out of file descriptors, in a process of its own
# --------------------------------------------------------------------------- #
EMFILE_SERVER = """
import asyncio, logging, resource, sys
from drivers.modbus_server import ModbusServer, ModbusServerConfig
logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(levelname)s %(name)s: %(message)s")

async def main():
    # a limit far above the fd limit: only the accept errors protect the process here
    server = ModbusServer(ModbusServerConfig(port=0, max_connections=5000, idle_timeout_s=0))
    await server.start()
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (64, hard))
    print(server.tcp_port, flush=True)
    await asyncio.sleep(float(sys.argv[1]))
    print(server.counters.accept_errors, server.counters.clients_connected, flush=True)
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    await server.stop()

asyncio.run(main())
"""


def test_out_of_file_descriptors_is_logged_once_not_a_traceback_per_attempt() -> None:
    hold_s = 3.0
    process = subprocess.Popen([sys.executable, "-c", EMFILE_SERVER, str(hold_s)], cwd=REPO,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = int(process.stdout.readline())
        flood = []
        for _ in range(150):
            flood.append(socket.create_connection(("127.0.0.1", port), timeout=2))
        out, err = process.communicate(timeout=30)
    finally:
        process.kill()
        for sock in flood:
            sock.close()
    accept_errors, connected = (int(v) for v in out.split())
    assert process.returncode == 0, err
    assert accept_errors >= 1 and connected < 64
    assert "Traceback" not in err
    accept_lines = [line for line in err.splitlines() if "cannot accept" in line]
    assert 1 <= len(accept_lines) <= 2, err[-2000:]
    assert len(err) < 2000, err[-2000:]


def test_new_config_keys_are_validated() -> None:
    for bad in ({"max_connections": 0}, {"idle_timeout_s": -1.0}, {"idle_timeout_s": float("nan")},
                {"peer_log_interval_s": 0.0}, {"priority_clients": ("nope",)}, {"device_name": "x" * 33},
                {"device_name": "Zürich"}):
        with pytest.raises(ModbusServerError):
            ModbusServerConfig(**bad)


def test_nothing_is_left_of_the_server_after_stop() -> None:
    async def scenario() -> None:
        server = ModbusServer(tcp_config(max_connections=3))
        await server.start()
        port = server.tcp_port
        socks = [socket.create_connection(("127.0.0.1", port)) for _ in range(5)]
        await asyncio.sleep(0.1)
        await server.stop()
        assert asyncio.get_running_loop().get_exception_handler() is None
        for sock in socks:
            sock.close()

    run(scenario())
