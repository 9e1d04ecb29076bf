"""The Modbus server against real clients: pymodbus and raw sockets (RTU and mbpoll: their own files)."""

from __future__ import annotations

import asyncio
import math
import random
import socket
import struct
import time

import numpy as np
import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers.modbus_map import (
    BY_NAME,
    HOLDING_SIZE,
    INPUT_REGISTERS,
    INPUT_SIZE,
    MAP_VERSION,
    VALUE_ROWS,
    WordOrder,
    encode_input_registers,
)
from drivers.modbus_server import ModbusServer, ModbusServerConfig, ModbusServerError
from drivers.published_values import Command, PublishedValues, StatusBits
from tests.modbus_helpers import (
    SAMPLE,
    decode,
    expected_raw,
    mbap,
    raw_exchange,
    read_table,
    serving,
    tcp_client,
    tcp_config,
)
from tests.wire_helpers import Recorder, run


# --------------------------------------------------------------------------- #
# Reading
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("order", [WordOrder.ABCD, WordOrder.CDAB])
def test_every_input_register_reads_back_the_published_values(order: WordOrder) -> None:
    async def scenario() -> None:
        async with serving(tcp_config(word_order=order)) as server:
            assert server.tcp_port and server.tcp_port > 0
            async with tcp_client(server.tcp_port) as client:
                words = await read_table(client)
                server_rows = {r.name for r in INPUT_REGISTERS if r.source.startswith("server.")}
                for row in INPUT_REGISTERS:
                    if row.name in server_rows:
                        continue
                    assert decode(client, words, row.name, order) == expected_raw(row.name, SAMPLE), row.name
                # the server's own rows: this is the first request of the first client
                assert decode(client, words, "MODBUS_REQUESTS", order) == 1
                assert decode(client, words, "MODBUS_CLIENTS", order) == 1
                assert decode(client, words, "MODBUS_EXCEPTIONS", order) == 0
                assert decode(client, words, "LAST_COMMAND_RESULT", order) == 0
                # scaled values mean what the table says they mean
                um = decode(client, words, "POSITION_UM", order)
                assert um * BY_NAME["POSITION_UM"].scale == pytest.approx(SAMPLE.position_m, abs=1e-6)
                holding = await client.read_holding_registers(0, count=2, device_id=1)
                assert holding.registers == [0, 0]

    run(scenario())


def test_a_read_of_part_of_the_table_answers_that_part_of_the_same_image() -> None:
    requests_row = BY_NAME["MODBUS_REQUESTS"]

    async def scenario() -> None:
        async with serving(tcp_config()) as server, tcp_client(server.tcp_port) as client:
            whole = await read_table(client)
            rng = random.Random(12)
            for n in range(2, 40):
                address = rng.randrange(INPUT_SIZE)
                count = rng.randint(1, INPUT_SIZE - address)
                response = await client.read_input_registers(address, count=count, device_id=1)
                assert not response.isError(), (address, count)
                part = list(response.registers)
                assert len(part) == count
                for offset, word in enumerate(part):
                    at = address + offset
                    if requests_row.address <= at < requests_row.address + requests_row.words:
                        continue
                    assert word == whole[at], (address, count, at)
                # the request counter in the answer counts this request
                if address <= requests_row.address and requests_row.address + 2 <= address + count:
                    i = requests_row.address - address
                    assert (part[i] << 16 | part[i + 1]) == n, (address, count)

    run(scenario())


def test_each_read_shows_the_newest_snapshot_whole_and_nothing_of_the_one_before() -> None:
    # the image is updated in place per snapshot (the server's own rows kept): a bit or a
    # word of an earlier snapshot must not survive — e.g. SCALED_CLAMPED of a clamped one
    clamped = PublishedValues(position_m=math.inf, velocity_mps=-1.0, status=StatusBits.VALID, heartbeat=1)
    snapshots = [SAMPLE, clamped, PublishedValues(heartbeat=2), SAMPLE, clamped, SAMPLE]

    async def scenario() -> None:
        async with serving(tcp_config()) as server, tcp_client(server.tcp_port) as client:
            for values in snapshots:
                server.update(values)
                words = await read_table(client)
                fresh = encode_input_registers(values)
                for row in VALUE_ROWS:
                    span = slice(row.address, row.address + row.words)
                    assert words[span] == fresh[span], (row.name, values)
                clamped_bit = bool(words[BY_NAME["STATUS"].address] & StatusBits.SCALED_CLAMPED)
                assert clamped_bit == (values is clamped)

    run(scenario())


def test_values_given_as_a_function_are_built_only_when_a_client_reads() -> None:
    """update() with a function (what the daemon does per sample): called at the next
    read, once per update however many reads follow, never without a read."""
    calls: list[int] = []

    def build() -> PublishedValues:
        calls.append(1)
        return PublishedValues(position_m=float(len(calls)), status=StatusBits.VALID)

    async def scenario() -> list[float]:
        async with serving(tcp_config()) as server, tcp_client(server.tcp_port) as client:
            for _ in range(100):
                server.update(build)  # many updates, no read
            assert calls == []
            seen = [decode(client, await read_table(client), "POSITION", WordOrder.ABCD) for _ in range(3)]
            server.update(build)
            seen.append(decode(client, await read_table(client), "POSITION", WordOrder.ABCD))
            return seen

    assert run(scenario()) == [1.0, 1.0, 1.0, 2.0]
    assert len(calls) == 2


def test_a_register_pair_never_mixes_two_snapshots() -> None:
    a = PublishedValues(position_m=1.0, velocity_mps=-3.0, status=StatusBits.VALID)
    b = PublishedValues(position_m=-2.5e3, velocity_mps=7.0e2, status=StatusBits.STALE)

    async def scenario() -> None:
        async with serving(tcp_config(), values=a) as server:

            async def flip() -> None:
                while True:
                    server.update(a)
                    await asyncio.sleep(0)
                    server.update(b)
                    await asyncio.sleep(0)

            flipper = asyncio.create_task(flip())
            seen = set()
            try:
                async with tcp_client(server.tcp_port) as client:
                    for _ in range(300):
                        response = await client.read_input_registers(0, count=16, device_id=1)
                        words = list(response.registers)
                        snapshot = (
                            decode(client, words, "POSITION", WordOrder.ABCD),
                            decode(client, words, "VELOCITY", WordOrder.ABCD),
                            decode(client, words, "POSITION_UM", WordOrder.ABCD),
                            words[BY_NAME["STATUS"].address],
                        )
                        assert snapshot in {
                            (1.0, -3.0, 1_000_000, int(StatusBits.VALID)),
                            # -2500 m is beyond int32 µm: clamped, and flagged in the same image
                            (-2500.0, 700.0, -(2**31 - 1), int(StatusBits.STALE | StatusBits.SCALED_CLAMPED)),
                        }, snapshot
                        seen.add(snapshot[0])
            finally:
                flipper.cancel()
            assert seen == {1.0, -2500.0}, "the test did not exercise both snapshots"

    run(scenario())


# --------------------------------------------------------------------------- #
# Commands
# --------------------------------------------------------------------------- #


def test_tare_is_executed_echoed_and_auto_cleared() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True), recorder) as server:
            async with tcp_client(server.tcp_port) as client:
                response = await client.write_register(0, 1, device_id=1)
                assert not response.isError(), response
                assert response.registers == [1]  # FC06 echoes the request
                assert (await client.read_holding_registers(0, count=2, device_id=1)).registers == [0, 0]
                words = await read_table(client)
                assert decode(client, words, "COMMAND_COUNTER", WordOrder.ABCD) == 1
                assert decode(client, words, "LAST_COMMAND_RESULT", WordOrder.ABCD) == 1
                zero = await client.write_register(1, 0, device_id=1)  # 0 = nothing to do
                assert not zero.isError()
            assert server.counters.commands_done == 1

    run(scenario())
    assert len(recorder.calls) == 1
    command, source = recorder.calls[0]
    assert command is Command.TARE
    assert source.startswith("modbus-tcp:127.0.0.1:")


def test_write_multiple_runs_commands_in_address_order() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with (
            serving(tcp_config(writes_enabled=True), recorder) as server,
            tcp_client(server.tcp_port) as client,
        ):
            response = await client.write_registers(0, [1, 1], device_id=1)
            assert not response.isError(), response

    run(scenario())
    assert [c for c, _ in recorder.calls] == [Command.TARE, Command.REESTIMATE_BIAS]


def test_writes_are_refused_when_disabled() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=False), recorder) as server:
            async with tcp_client(server.tcp_port) as client:
                for request in (client.write_register(0, 1, device_id=1),
                                client.write_registers(0, [1, 1], device_id=1)):
                    response = await request
                    assert response.isError() and response.exception_code == 1
                words = await read_table(client)
                assert decode(client, words, "MODBUS_REJECTED_WRITES", WordOrder.ABCD) == 2
                assert decode(client, words, "MODBUS_EXCEPTIONS", WordOrder.ABCD) == 2
                assert decode(client, words, "COMMAND_COUNTER", WordOrder.ABCD) == 0
            assert server.counters.rejected_writes == 2

    run(scenario())
    assert recorder.calls == []


@pytest.mark.parametrize("allow_entry", ["127.0.0.2", "127.0.0.2/32", "127.0.0.0/31"])
def test_write_allow_list_admits_only_listed_clients(allow_entry: str) -> None:
    recorder = Recorder()
    admitted_ip = "127.0.0.1" if allow_entry == "127.0.0.0/31" else "127.0.0.2"
    refused_ip = "127.0.0.2" if allow_entry == "127.0.0.0/31" else "127.0.0.1"

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True, write_allow=(allow_entry,)), recorder) as server:
            async with tcp_client(server.tcp_port, source_ip=refused_ip) as outsider:
                response = await outsider.write_register(0, 1, device_id=1)
                assert response.isError() and response.exception_code == 1
                # reading is still fine for everybody
                assert not (await outsider.read_input_registers(0, count=2, device_id=1)).isError()
            assert recorder.calls == []
            async with tcp_client(server.tcp_port, source_ip=admitted_ip) as insider:
                response = await insider.write_register(0, 1, device_id=1)
                assert not response.isError(), response
            assert server.counters.rejected_writes == 1

    run(scenario())
    assert len(recorder.calls) == 1
    assert recorder.calls[0][1].startswith(f"modbus-tcp:{admitted_ip}:")


def test_an_empty_allow_list_admits_nobody() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with (
            serving(tcp_config(writes_enabled=True, write_allow=()), recorder) as server,
            tcp_client(server.tcp_port) as client,
        ):
            response = await client.write_register(0, 1, device_id=1)
            assert response.isError() and response.exception_code == 1

    run(scenario())
    assert recorder.calls == []


@pytest.mark.parametrize(
    "answer, result_code, counter_name",
    [(False, 2, "commands_declined"), (RuntimeError("daemon bug"), 3, "commands_failed")],
)
def test_declined_or_failing_command_answers_04(answer, result_code: int, counter_name: str) -> None:
    recorder = Recorder(answer)

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True), recorder) as server:
            async with tcp_client(server.tcp_port) as client:
                response = await client.write_register(1, 1, device_id=1)
                assert response.isError() and response.exception_code == 4
                words = await read_table(client)
                assert decode(client, words, "LAST_COMMAND_RESULT", WordOrder.ABCD) == result_code
                assert decode(client, words, "COMMAND_COUNTER", WordOrder.ABCD) == 1
                # the server survived the daemon's exception
                assert (await client.read_holding_registers(0, count=2, device_id=1)).registers == [0, 0]
            assert getattr(server.counters, counter_name) == 1

    run(scenario())
    assert [c for c, _ in recorder.calls] == [Command.REESTIMATE_BIAS]


def test_illegal_values_addresses_and_functions() -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True), recorder) as server:
            async with tcp_client(server.tcp_port) as client:
                cases = [
                    (client.write_register(0, 2, device_id=1), 3),
                    (client.write_registers(0, [1, 7], device_id=1), 3),
                    (client.write_register(HOLDING_SIZE, 1, device_id=1), 2),
                    (client.read_input_registers(INPUT_SIZE, count=1, device_id=1), 2),
                    (client.read_input_registers(INPUT_SIZE - 1, count=2, device_id=1), 2),
                    (client.read_holding_registers(0, count=HOLDING_SIZE + 1, device_id=1), 2),
                    (client.read_coils(0, count=1, device_id=1), 1),
                    (client.write_coil(0, True, device_id=1), 1),
                    (client.read_discrete_inputs(0, count=1, device_id=1), 1),
                ]
                for request, code in cases:
                    response = await request
                    assert response.isError() and response.exception_code == code, response
                # the last valid register is readable
                assert not (await client.read_input_registers(INPUT_SIZE - 1, count=1, device_id=1)).isError()
            assert server.counters.exceptions == len(cases)

    run(scenario())
    assert recorder.calls == []


# --------------------------------------------------------------------------- #
# Robustness
# --------------------------------------------------------------------------- #




def test_malformed_requests_do_not_disturb_other_clients() -> None:
    rng = random.Random(20240611)

    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            port = server.tcp_port
            async with tcp_client(port) as bystander:
                before = await read_table(bystander)
                # answered with the request's own function code and the proper exception
                assert await raw_exchange(port, mbap(1, b"\x41\x00\x00")) == mbap(1, b"\xc1\x01")  # unknown function
                assert await raw_exchange(port, mbap(2, b"\x04\x00\x00\x00\x00")) == mbap(2, b"\x84\x03")  # count 0
                assert await raw_exchange(port, mbap(3, b"\x04\x00\x00\x00\xc8")) == mbap(3, b"\x84\x03")  # count 200
                assert await raw_exchange(port, mbap(4, b"\x04\x00")) == mbap(4, b"\x84\x03")  # truncated
                # an extra byte: still one answer
                assert await raw_exchange(port, mbap(5, b"\x03\x00\x00\x00\x01\x09")) != b""
                # not Modbus at all: no answer, no crash
                assert await raw_exchange(port, mbap(6, b"\x04\x00\x00\x00\x01", protocol=5)) == b""
                assert await raw_exchange(port, struct.pack(">HHHB", 7, 0, 60000, 1) + b"\x04") == b""
                for _ in range(20):
                    blob = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 600)))
                    await raw_exchange(port, blob, wait_s=0.02)
                # two requests in one TCP segment: two answers, in order
                both = await raw_exchange(port, mbap(10, b"\x04\x00\x00\x00\x01") + mbap(11, b"\x04\x00\x00\x00\x01"))
                version = struct.pack(">H", MAP_VERSION)
                assert both == mbap(10, b"\x04\x02" + version) + mbap(11, b"\x04\x02" + version)
                # the client that was connected all along still works, and so does a new one
                after = await read_table(bystander)
                assert after[: BY_NAME["MODBUS_REQUESTS"].address] == before[: BY_NAME["MODBUS_REQUESTS"].address]
            async with tcp_client(port) as newcomer:
                assert decode(newcomer, await read_table(newcomer), "POSITION", WordOrder.ABCD) == float(
                    np.float32(SAMPLE.position_m)
                )
            assert server.counters.exceptions >= 4

    run(scenario())


@pytest.mark.parametrize(
    "pdu",
    [
        b"\x10\x00\x00\x00\x02\x09\x00\x01\x00\x01",  # FC16 byte count says 9, 4 follow
        b"\x10\x00\x00\x00\x02\x04\x00\x01",  # FC16 two registers announced, one sent
        b"\x10\x00\x00\x00\x00\x00",  # FC16 quantity 0
        b"\x06\x00\x00",  # FC06 without a value
    ],
)
def test_malformed_writes_get_03_and_execute_nothing(pdu: bytes) -> None:
    recorder = Recorder()

    async def scenario() -> None:
        async with serving(tcp_config(writes_enabled=True), recorder) as server:
            answer = await raw_exchange(server.tcp_port, mbap(9, pdu))
            assert answer == mbap(9, bytes([pdu[0] | 0x80, 3]))

    run(scenario())
    assert recorder.calls == []


def test_clients_that_connect_and_drop_leave_no_trace() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            port = server.tcp_port
            for i in range(30):
                sock = socket.create_connection(("127.0.0.1", port))
                if i % 3 == 0:  # reset instead of a clean close
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                if i % 3 == 1:  # half a request, then gone
                    sock.sendall(mbap(i, b"\x04\x00\x00\x00\x02")[:5])
                await asyncio.sleep(0.005)
                sock.close()
            deadline = time.monotonic() + 5
            while server.counters.clients_connected and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
            assert server.counters.clients_connected == 0
            assert server.counters.connections_total == 30
            async with tcp_client(port) as client:
                words = await read_table(client)
                assert decode(client, words, "MODBUS_CLIENTS", WordOrder.ABCD) == 1

    run(scenario())


def test_stop_is_quick_with_clients_connected_and_the_port_is_free_again() -> None:
    async def scenario() -> None:
        server = ModbusServer(tcp_config())
        await server.start()
        port = server.tcp_port
        clients = [AsyncModbusTcpClient("127.0.0.1", port=port, retries=0, reconnect_delay=0) for _ in range(5)]
        for client in clients:
            assert await client.connect()
            assert not (await client.read_input_registers(0, count=1, device_id=1)).isError()
        started = time.monotonic()
        await server.stop()
        assert time.monotonic() - started < 2.0
        for client in clients:
            client.close()
        # the same port can be served again at once
        again = ModbusServer(tcp_config(port=port))
        await again.start()
        assert again.tcp_port == port
        await again.stop()

    run(scenario())


def test_start_on_a_busy_port_raises_modbus_server_error() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as first:
            second = ModbusServer(tcp_config(port=first.tcp_port))
            with pytest.raises(ModbusServerError):
                await second.start()

    run(scenario())


@pytest.mark.parametrize(
    "overrides",
    [{"port": 70000}, {"unit_id": 248}, {"rtu_enabled": True, "unit_id": 0}, {"rtu_parity": "X"},
     {"word_order": "BADC"}, {"write_allow": ("not-an-address",)}],
)
def test_config_validation(overrides: dict) -> None:
    with pytest.raises(ModbusServerError):
        ModbusServerConfig(**overrides)
