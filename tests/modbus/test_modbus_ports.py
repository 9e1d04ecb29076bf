"""Modbus ports that cannot be used, with their causes: RTU settings a port cannot take
(a pty refuses parity E), a missing or lost RTU port (retried, status bit set), a TCP
port already in use — from the server and from `adxlgw run` (exit 3, one line)."""
from __future__ import annotations

import asyncio
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.modbus_map import WordOrder
from drivers.modbus_server import ModbusServer, ModbusServerConfig, ModbusServerError
from drivers.published_values import StatusBits
from tests.modbus_helpers import decode, read_table, rtu_client, serving, tcp_client, tcp_config
from tests.wire_helpers import run

REPO = Path(__file__).resolve().parents[2]
SOCAT = shutil.which("socat")
ADXLGW = Path(sys.executable).with_name("adxlgw")
needs_socat = pytest.mark.skipif(SOCAT is None, reason="socat not installed (Debian package socat)")


def tcp_and_rtu(rtu_port: Path, rtu_parity: str = "N") -> ModbusServerConfig:
    return ModbusServerConfig(host="127.0.0.1", port=0, rtu_enabled=True, rtu_port=str(rtu_port), unit_id=7,
                              rtu_parity=rtu_parity)


def start_pty_pair(server_end: Path, client_end: Path) -> subprocess.Popen:
    process = subprocess.Popen(
        [SOCAT, f"pty,raw,echo=0,link={server_end}", f"pty,raw,echo=0,link={client_end}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 5
    while not (server_end.exists() and client_end.exists()):
        assert process.poll() is None and time.monotonic() < deadline, "socat did not create the pty pair"
        time.sleep(0.01)
    return process


def stop(process: subprocess.Popen) -> None:
    process.terminate()
    process.wait(5)


async def status_of(server: ModbusServer) -> StatusBits:
    async with tcp_client(server.tcp_port) as client:
        return StatusBits(decode(client, await read_table(client), "STATUS", WordOrder.ABCD))


async def eventually(condition, within_s: float = 10.0) -> None:
    deadline = time.monotonic() + within_s
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        await asyncio.sleep(0.05)


@needs_socat
def test_rtu_parity_a_pty_cannot_take_is_one_line_and_tcp_is_released(tmp_path: Path) -> None:
    # pyserial raised termios.error: (22, 'Invalid argument') through pymodbus: a traceback
    socat = start_pty_pair(tmp_path / "server", tmp_path / "client")
    try:
        async def scenario() -> None:
            config = tcp_and_rtu(tmp_path / "server", rtu_parity="E")
            server = ModbusServer(config)
            with pytest.raises(ModbusServerError) as caught:
                await server.start()
            message = str(caught.value)
            assert "\n" not in message
            assert message.startswith(f"RTU port {tmp_path / 'server'} cannot take 19200 baud, 8E1: ")
            # and again on the same pty (where the kernel now answers EINVAL)
            with pytest.raises(ModbusServerError, match="cannot take 19200 baud, 8E1: "):
                await ModbusServer(config).start()
            assert server.tcp_port is None  # TCP was started first and closed again

        run(scenario())
    finally:
        stop(socat)


@needs_socat
def test_a_missing_rtu_port_is_retried_flagged_and_served_once_it_appears(tmp_path: Path) -> None:
    server_end, client_end = tmp_path / "server", tmp_path / "client"

    async def scenario() -> None:
        config = tcp_and_rtu(server_end)
        async with serving(config) as server:
            assert not server.rtu_serving
            assert StatusBits.MODBUS_RTU_DOWN in await status_of(server)
            socat = await asyncio.to_thread(start_pty_pair, server_end, client_end)
            try:
                await eventually(lambda: server.rtu_serving)
                async with rtu_client(str(client_end)) as client:
                    assert not (await client.read_input_registers(0, count=1, device_id=7)).isError()
                assert StatusBits.MODBUS_RTU_DOWN not in await status_of(server)
                # the other end goes away: lost, flagged, and back once it returns
                await asyncio.to_thread(stop, socat)
                await eventually(lambda: not server.rtu_serving)
                assert StatusBits.MODBUS_RTU_DOWN in await status_of(server)
                socat = await asyncio.to_thread(start_pty_pair, server_end, client_end)
                await eventually(lambda: server.rtu_serving)
                async with rtu_client(str(client_end)) as client:
                    assert not (await client.read_input_registers(0, count=1, device_id=7)).isError()
            finally:
                await asyncio.to_thread(stop, socat)
            assert server.counters.rtu_open_failures >= 2

    run(scenario(), timeout_s=60)


def test_a_tcp_port_in_use_is_named() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as first:
            second = ModbusServer(tcp_config(port=first.tcp_port))
            with pytest.raises(ModbusServerError) as caught:
                await second.start()
            assert str(caught.value).startswith(f"port {first.tcp_port} already in use on 127.0.0.1")

    run(scenario())


def test_a_host_that_is_not_on_this_machine_is_named() -> None:
    async def scenario() -> None:
        server = ModbusServer(tcp_config(host="192.0.2.1"))  # TEST-NET-1: never local
        with pytest.raises(ModbusServerError, match="address 192.0.2.1 is not an address of this machine"):
            await server.start()

    run(scenario())


# --------------------------------------------------------------------------- #
# The daemon: exit 3 with one line
# --------------------------------------------------------------------------- #
def run_daemon(tmp_path: Path, modbus: str) -> subprocess.CompletedProcess:
    config = tmp_path / "gateway.toml"
    config.write_text(
        '[serial]\nport = "emulated"\n'
        f"[modbus]\n{modbus}\n"
        "[can]\nenabled = false\n"
        f'[state]\npath = "{tmp_path / "state.json"}"\n'
    )
    return subprocess.run([str(ADXLGW), "run", "--config", str(config)], cwd=REPO, capture_output=True,
                          text=True, timeout=60, env={**os.environ, "NOTIFY_SOCKET": ""})


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line.lower()]


def test_run_with_the_modbus_port_taken_exits_3_naming_the_port(tmp_path: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        result = run_daemon(tmp_path, f"port = {port}")
    assert result.returncode == 3, result.stderr
    assert "Traceback" not in result.stderr
    # found by the start's check (preflight, the same as config --check), naming the file and key
    assert error_lines(result.stderr) == [
        f"adxlgw run: error: {tmp_path / 'gateway.toml'}: modbus.port: port {port} already in use on 127.0.0.1 "
        "(another Modbus server or gateway?)"
    ]


@needs_socat
def test_run_with_rtu_parity_e_on_a_pty_exits_3_with_one_line(tmp_path: Path) -> None:
    socat = start_pty_pair(tmp_path / "server", tmp_path / "client")
    try:
        result = run_daemon(tmp_path, f'port = 0\nrtu_enabled = true\nrtu_port = "{tmp_path / "server"}"')
    finally:
        stop(socat)
    assert result.returncode == 3, result.stderr
    assert "Traceback" not in result.stderr and "termios" not in result.stderr
    lines = error_lines(result.stderr)
    assert len(lines) == 1 and lines[0].startswith(
        f"adxlgw run: error: Modbus server: RTU port {tmp_path / 'server'} cannot take 19200 baud, 8E1: "), lines
