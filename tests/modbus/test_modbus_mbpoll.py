"""The Modbus server read by mbpoll, the command-line client a PLC integrator uses (PLC references)."""

from __future__ import annotations

import asyncio
import shutil
import subprocess

import pytest

from drivers.modbus_map import BY_NAME, MAP_VERSION, WordOrder
from tests.modbus_helpers import SAMPLE, serving, tcp_config
from tests.wire_helpers import run

# --------------------------------------------------------------------------- #
# mbpoll, a Modbus master written by other people
# --------------------------------------------------------------------------- #
MBPOLL = shutil.which("mbpoll")


async def mbpoll(port: int, *args: str) -> dict[int, str]:
    process = await asyncio.create_subprocess_exec(
        MBPOLL, "-m", "tcp", "-a", "1", "-1", "-o", "2", "-p", str(port), *args, "127.0.0.1",
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )
    out, err = await asyncio.wait_for(process.communicate(), 15)
    assert process.returncode == 0, err.decode()
    values = {}
    for line in out.decode().splitlines():
        if line.startswith("[") and "]:" in line:
            ref, value = line.split("]:", 1)
            values[int(ref.strip("["))] = value.strip()
    return values


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (Debian package mbpoll)")
def test_mbpoll_reads_the_documented_plc_references() -> None:
    async def scenario() -> None:
        async with serving(tcp_config()) as server:
            port = server.tcp_port
            # -r is 1-based: reference 1 is address 0 (MAP_VERSION), i.e. PLC 30001
            head = await mbpoll(port, "-r", "1", "-c", "3", "-t", "3")
            assert head == {1: str(MAP_VERSION), 2: str(int(SAMPLE.status)), 3: str(SAMPLE.heartbeat % 65536)}
            position_ref = BY_NAME["POSITION"].plc_reference - 30000
            floats = await mbpoll(port, "-r", str(position_ref), "-c", "1", "-t", "3:float", "-B")
            assert float(floats[position_ref]) == pytest.approx(SAMPLE.position_m, rel=1e-6)
            um_ref = BY_NAME["POSITION_UM"].plc_reference - 30000
            ints = await mbpoll(port, "-r", str(um_ref), "-c", "1", "-t", "3:int", "-B")
            assert int(ints[um_ref]) == round(SAMPLE.position_m * 1e6)
            temp_ref = BY_NAME["BOARD_TEMPERATURE"].plc_reference - 30000
            temp = await mbpoll(port, "-r", str(temp_ref), "-c", "1", "-t", "3")
            assert int(temp[temp_ref]) == round(SAMPLE.board_temp_c * 100)

        # mbpoll's default 32-bit order is low word first: our CDAB
        async with serving(tcp_config(word_order=WordOrder.CDAB)) as server:
            position_ref = BY_NAME["VELOCITY"].plc_reference - 30000
            floats = await mbpoll(server.tcp_port, "-r", str(position_ref), "-c", "1", "-t", "3:float")
            assert float(floats[position_ref]) == SAMPLE.velocity_mps

    run(scenario())
