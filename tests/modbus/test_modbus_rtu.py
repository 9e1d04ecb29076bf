"""The Modbus server on RTU: pymodbus's serial client over a pty pair made by socat."""

from __future__ import annotations

import math
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from pymodbus.exceptions import ModbusException

from drivers.modbus_map import WordOrder
from drivers.published_values import Command, PublishedValues, StatusBits
from tests.modbus_helpers import (
    SAMPLE,
    decode,
    expected_raw,
    read_table,
    rtu_client,
    rtu_config,
    serving,
    tcp_client,
    tcp_config,
)
from tests.wire_helpers import Recorder, run

# --------------------------------------------------------------------------- #
# RTU over a pty pair made by socat
# --------------------------------------------------------------------------- #
SOCAT = shutil.which("socat")


@pytest.fixture
def pty_pair(tmp_path: Path):
    if SOCAT is None:
        pytest.skip("socat not installed (Debian package socat)")
    server_end, client_end = tmp_path / "server", tmp_path / "client"
    process = subprocess.Popen(
        [SOCAT, "-d", "-d", f"pty,raw,echo=0,link={server_end}", f"pty,raw,echo=0,link={client_end}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 5
    while not (server_end.exists() and client_end.exists()):
        assert process.poll() is None, process.stderr.read().decode()
        assert time.monotonic() < deadline, "socat did not create the pty pair"
        time.sleep(0.01)
    try:
        yield str(server_end), str(client_end)
    finally:
        process.terminate()
        process.wait(5)
        process.stderr.close()






def test_rtu_serves_the_same_registers_and_only_its_unit_id(pty_pair) -> None:
    server_end, client_end = pty_pair
    recorder = Recorder()

    async def scenario() -> None:
        async with serving(rtu_config(server_end, writes_enabled=True), recorder) as server:
            assert server.tcp_port is None
            async with rtu_client(client_end) as client:
                words = await read_table(client, device_id=7)
                for name in ("POSITION", "VELOCITY_UM_S", "SAMPLE_COUNTER", "BOARD_TEMPERATURE", "STATUS"):
                    assert decode(client, words, name, WordOrder.ABCD) == expected_raw(name, SAMPLE), name
                # writes need rtu_writes_enabled on top of writes_enabled
                refused = await client.write_register(0, 1, device_id=7)
                assert refused.isError() and refused.exception_code == 1
            async with rtu_client(client_end, timeout_s=0.3) as client:
                # another device's unit id: silence, so a real device 3 could answer
                with pytest.raises(ModbusException):
                    await client.read_input_registers(0, count=1, device_id=3)
            async with rtu_client(client_end) as client:
                assert not (await client.read_input_registers(0, count=1, device_id=7)).isError()
            assert server.counters.rejected_writes == 1

    run(scenario())
    assert recorder.calls == []


def test_rtu_writes_when_enabled_name_the_serial_port(pty_pair) -> None:
    server_end, client_end = pty_pair
    recorder = Recorder()

    async def scenario() -> None:
        config = rtu_config(server_end, writes_enabled=True, rtu_writes_enabled=True)
        async with serving(config, recorder), rtu_client(client_end) as client:
            response = await client.write_register(0, 1, device_id=7)
            assert not response.isError(), response

    run(scenario())
    assert recorder.calls == [(Command.TARE, f"modbus-rtu:{server_end}:unit7")]


def test_tcp_and_rtu_share_one_image(pty_pair) -> None:
    server_end, client_end = pty_pair

    async def scenario() -> None:
        config = tcp_config(rtu_enabled=True, rtu_port=server_end, unit_id=7, rtu_parity="N")
        async with serving(config) as server:
            server.update(PublishedValues(position_m=-4.5, status=StatusBits.VALID))
            async with tcp_client(server.tcp_port) as tcp, rtu_client(client_end) as rtu:
                for client, device_id in ((tcp, 1), (rtu, 7)):
                    words = await read_table(client, device_id=device_id)
                    assert decode(client, words, "POSITION", WordOrder.ABCD) == -4.5
                    assert math.isnan(decode(client, words, "VELOCITY", WordOrder.ABCD))
                # both wires count into the same counters
                assert server.counters.requests == 2

    run(scenario())
