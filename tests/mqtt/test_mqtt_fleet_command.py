"""`adxlgw fleet` as a person or a script runs it, against a real mosquitto with two
gateways on it: both shown, the one that stops shown dead, the numbers the gateway
publishes; a broker that is not there is exit code 3."""
from __future__ import annotations

import asyncio
import json
import math
import sys

from testing.mqtt_helpers import Broker, free_port
from tests.daemon_helpers import gateway_config, running_gateway, wait_for

GROUP = "line-7"
WAIT_S = 30
CLI = [sys.executable, "-m", "gateway.cli"]


def node_config(tmp_path, port: int, node: str):
    return gateway_config(tmp_path / node, "emulated",
                          mqtt={"enabled": True, "port": port, "group_id": GROUP, "edge_node_id": node})


async def fleet(*args: str):
    """The command started, and the coroutine that waits for its output."""
    proc = await asyncio.create_subprocess_exec(*CLI, "fleet", *args, stdout=asyncio.subprocess.PIPE,
                                                stderr=asyncio.subprocess.PIPE)
    return proc, proc.communicate()


def test_fleet_shows_every_gateway_and_the_death_of_one(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with Broker(tmp_path) as broker:
        async def scenario():
            async with running_gateway(node_config(tmp_path, broker.port, "a")) as a:
                async with running_gateway(node_config(tmp_path, broker.port, "b")) as b:
                    await wait_for(lambda: a.mqtt.counters.births == 1 and b.mqtt.counters.births == 1, WAIT_S,
                                   what="both born")
                    proc, output = await fleet("--broker", f"127.0.0.1:{broker.port}", "--json", "--seconds", "8")
                    # the host view hears their data without their births: it asks each for a rebirth
                    await wait_for(lambda: a.mqtt.counters.births == 2 and b.mqtt.counters.births == 2, WAIT_S,
                                   what="the fleet's rebirth requests")
                    position_a = a.fresh_values().position_m
                # b stopped: its NDEATH
                out, err = await output
                assert proc.returncode == 0, err
                table_proc, table_output = await fleet("--broker", f"127.0.0.1:{broker.port}", "--seconds", "3")
                table, table_err = await table_output
                assert table_proc.returncode == 0, table_err
            return json.loads(out), table.decode(), position_a

        report, table, position_a = asyncio.run(scenario())
    rows = {r["node"]: r for r in report["nodes"]}
    assert set(rows) == {"a", "b"}
    assert rows["a"]["online"] is True and rows["b"]["online"] is False
    assert rows["a"]["group"] == GROUP and rows["a"]["device"] == "axis"
    # a number the gateway published (its value moves with the emulated axis while the fleet listens)
    assert isinstance(rows["a"]["position_m"], float) and math.isfinite(rows["a"]["position_m"])
    assert isinstance(rows["a"]["status"], int) and isinstance(position_a, float)
    assert rows["a"]["lost"] == 0
    header, *lines = table.splitlines()
    assert header.split()[:4] == ["group", "node", "device", "state"]
    assert any(line.split()[:4] == [GROUP, "a", "axis", "online"] for line in lines), table


def test_fleet_without_a_broker_is_exit_code_3(tmp_path):
    async def scenario():
        proc, output = await fleet("--broker", f"127.0.0.1:{free_port()}", "--json")
        _, err = await output
        return proc.returncode, err.decode()

    code, err = asyncio.run(scenario())
    assert code == 3 and "broker 127.0.0.1:" in err
