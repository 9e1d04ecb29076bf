"""Shared parts of the Modbus server tests: a server serving a sample image, pymodbus
TCP and RTU clients, raw MBAP frames, a command recorder, and the register table read back."""
from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import AsyncIterator, Callable

import numpy as np
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from drivers.modbus_map import (
    BY_NAME,
    INPUT_SIZE,
    MAP_VERSION,
    RegType,
    WordOrder,
)
from drivers.modbus_server import ModbusServer, ModbusServerConfig
from drivers.published_values import PublishedValues, StatusBits

DT = AsyncModbusTcpClient.DATATYPE


PYMODBUS_ORDER = {WordOrder.ABCD: "big", WordOrder.CDAB: "little"}


CLIENT_TYPE = {
    RegType.FLOAT32: DT.FLOAT32,
    RegType.INT32: DT.INT32,
    RegType.UINT32: DT.UINT32,
    RegType.UINT16: DT.UINT16,
    RegType.INT16: DT.INT16,
    RegType.BITFIELD: DT.UINT16,
}


SAMPLE = PublishedValues(
    position_m=0.123456,
    velocity_mps=-0.75,
    acceleration_mps2=9.80665,
    status=StatusBits.VALID | StatusBits.STANDSTILL | StatusBits.NOT_REFERENCED,
    heartbeat=70000,  # wraps to 4464 on the wire
    sample_counter=123456789,
    last_sample_age_ms=3.4,
    bias_estimate_mps2=-0.0123,
    position_std_m=0.0015,
    board_temp_c=31.27,
    lost_samples=5,
    crc_errors=2,
    board_resets=1,
    can_send_errors=9,
)




def tcp_config(**overrides) -> ModbusServerConfig:
    return ModbusServerConfig(**{"host": "127.0.0.1", "port": 0, **overrides})


@contextlib.asynccontextmanager
async def serving(
    config: ModbusServerConfig, on_command: Callable | None = None, values: PublishedValues = SAMPLE
) -> AsyncIterator[ModbusServer]:
    server = ModbusServer(config, on_command)
    await server.start()
    server.update(values)
    try:
        yield server
    finally:
        await server.stop()


@contextlib.asynccontextmanager
async def tcp_client(port: int, source_ip: str | None = None) -> AsyncIterator[AsyncModbusTcpClient]:
    client = AsyncModbusTcpClient(
        "127.0.0.1",
        port=port,
        source_address=(source_ip, 0) if source_ip else None,
        timeout=2,
        retries=0,
        reconnect_delay=0,
    )
    assert await client.connect()
    try:
        yield client
    finally:
        client.close()


def expected_raw(name: str, values: PublishedValues) -> float | int:
    """What a client must read, from the published values and the table's scale."""
    row = BY_NAME[name]
    value = {"MAP_VERSION": MAP_VERSION, "STATUS": int(values.status)}.get(name)
    if value is None:
        value = getattr(values, row.source)
    if row.type is RegType.FLOAT32:
        return float(np.float32(value))
    if row.wraps:
        return int(value) % 2 ** (16 * row.words)
    return round(value / row.scale)


async def read_table(client: AsyncModbusTcpClient | AsyncModbusSerialClient, device_id: int = 1) -> list[int]:
    response = await client.read_input_registers(0, count=INPUT_SIZE, device_id=device_id)
    assert not response.isError(), response
    return list(response.registers)


def decode(client, words: list[int], name: str, order: WordOrder) -> float | int:
    row = BY_NAME[name]
    regs = words[row.address : row.address + row.words]
    return client.convert_from_registers(regs, CLIENT_TYPE[row.type], word_order=PYMODBUS_ORDER[order])




def mbap(transaction: int, pdu: bytes, unit: int = 1, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", transaction, protocol, len(pdu) + 1, unit) + pdu


async def raw_exchange(port: int, data: bytes, wait_s: float = 0.3) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        await writer.drain()
        try:
            return await asyncio.wait_for(reader.read(1024), wait_s)
        except TimeoutError:
            return b""
    finally:
        writer.close()


def rtu_config(port: str, **overrides) -> ModbusServerConfig:
    return ModbusServerConfig(
        # a pty rejects parity settings (EINVAL); real RS-485 lines use the E default
        **{"tcp_enabled": False, "rtu_enabled": True, "rtu_port": port, "unit_id": 7, "rtu_parity": "N", **overrides}
    )


@contextlib.asynccontextmanager
async def rtu_client(port: str, timeout_s: float = 1.0) -> AsyncIterator[AsyncModbusSerialClient]:
    client = AsyncModbusSerialClient(port, baudrate=19200, parity="N", timeout=timeout_s, retries=0, reconnect_delay=0)
    assert await client.connect()
    try:
        yield client
    finally:
        client.close()
