"""Who the gateway is on Modbus: device identification (FC 43/14) read by pymodbus's client
and by raw frames, and the identity registers."""
from __future__ import annotations

import struct

import pytest
from pymodbus.constants import ExcCodes

from drivers.modbus_identity import DeviceIdentity, device_information, package_version, version_numbers
from drivers.modbus_map import BY_NAME, MAP_VERSION, WordOrder
from tests.modbus_helpers import decode, mbap, raw_exchange, read_table, serving, tcp_client, tcp_config
from tests.wire_helpers import run

NAME = "press 7 / ram"


def expected_objects() -> dict[int, bytes]:
    return {
        0x00: b"adxl-gateway project",
        0x01: b"ADXLGW",
        0x02: package_version().encode(),
        0x04: b"adxl-gateway",
        0x05: b"ADXL202 serial-to-Modbus/CAN gateway",
        0x06: NAME.encode(),
        0x80: f"register map {MAP_VERSION}".encode(),
    }


@pytest.mark.parametrize("read_code, ids", [(1, [0, 1, 2]), (2, [0, 1, 2, 4, 5, 6]), (3, [0, 1, 2, 4, 5, 6, 0x80])])
def test_pymodbus_client_reads_the_identification_streams(read_code: int, ids: list[int]) -> None:
    async def scenario() -> None:
        async with serving(tcp_config(device_name=NAME)) as server, tcp_client(server.tcp_port) as client:
            response = await client.read_device_information(read_code=read_code, object_id=0, device_id=1)
            assert not response.isError(), response
            assert response.information == {k: expected_objects()[k] for k in ids}
            assert response.conformity == 0x83 and response.more_follows == 0

    run(scenario())


def test_individual_access_and_bad_requests() -> None:
    async def scenario() -> None:
        async with serving(tcp_config(device_name=NAME)) as server:
            async with tcp_client(server.tcp_port) as client:
                one = await client.read_device_information(read_code=4, object_id=6, device_id=1)
                assert one.information == {6: NAME.encode()}
                missing = await client.read_device_information(read_code=4, object_id=3, device_id=1)
                assert missing.isError() and missing.exception_code == 2  # no vendor URL served
            # read code 5 does not exist: 03; another MEI type (13, CANopen): 01
            assert await raw_exchange(server.tcp_port, mbap(1, b"\x2b\x0e\x05\x00")) == mbap(1, b"\xab\x03")
            assert await raw_exchange(server.tcp_port, mbap(2, b"\x2b\x0d\x00\x00")) == mbap(2, b"\xab\x01")
            # a stream starting at an object that does not exist restarts at 0 (the spec)
            answer = await raw_exchange(server.tcp_port, mbap(3, b"\x2b\x0e\x01\x03"))
            assert answer[7:14] == b"\x2b\x0e\x01\x83\x00\x00\x03"  # read code 1, conformity, 3 objects

    run(scenario())


def test_identity_registers_read_version_and_name() -> None:
    async def scenario() -> None:
        async with serving(tcp_config(device_name=NAME)) as server, tcp_client(server.tcp_port) as client:
            words = await read_table(client)
            version = tuple(decode(client, words, n, WordOrder.ABCD)
                            for n in ("VERSION_MAJOR", "VERSION_MINOR", "VERSION_PATCH"))
            assert version == version_numbers(package_version())
            # a PLC reads the name as 16 registers of two ASCII characters
            row = BY_NAME["DEVICE_NAME"]
            raw = struct.pack(">16H", *words[row.address: row.address + 16])
            assert raw == NAME.encode().ljust(32, b"\0")

    run(scenario())


def test_object_selection_follows_the_spec() -> None:
    identity = DeviceIdentity(device_name="", revision="1.2.3", map_version=9)
    assert list(device_information(identity, 1, 0)) == [0, 1, 2]
    assert list(device_information(identity, 1, 2)) == [2]  # stream from object 2
    assert list(device_information(identity, 2, 0)) == [0, 1, 2, 4, 5]  # no name configured: not sent
    assert list(device_information(identity, 3, 0x80)) == [0x80]
    assert device_information(identity, 4, 6) is ExcCodes.ILLEGAL_ADDRESS
    assert device_information(identity, 0, 0) is ExcCodes.ILLEGAL_VALUE
    assert device_information(identity, 4, 2) == {2: b"1.2.3"}


@pytest.mark.parametrize("text, numbers", [("0.1.0", (0, 1, 0)), ("2.10", (2, 10, 0)), ("1.2.3rc1", (1, 2, 3)),
                                           ("0.0.0+unknown", (0, 0, 0)), ("x.y.z", (0, 0, 0)),
                                           ("99999.1.1", (65535, 1, 1))])
def test_version_numbers(text: str, numbers: tuple[int, int, int]) -> None:
    assert version_numbers(text) == numbers
