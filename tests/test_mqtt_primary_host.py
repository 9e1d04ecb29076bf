"""Sparkplug 3.0's primary host, against a real mosquitto: an edge node with
`primary_host_id` is born only once the host's retained STATE says online, keeps its data
meanwhile, ends its session (NDEATH, disconnect, connect again) when the host says
offline, ignores a STATE older than the newest (a late death of a host session already
over), and counts a STATE that is not one."""
from __future__ import annotations

import asyncio
import json

import paho.mqtt.client as mqtt

from drivers import sparkplug_payload as spb
from drivers.published_values import PublishedValues, StatusBits
from drivers.sparkplug_host import FleetListener
from drivers.sparkplug_node import SparkplugNode, SparkplugSettings
from testing.mqtt_helpers import Broker
from tests.daemon_helpers import wait_for

GROUP = "plant-test"
HOST_ID = "scada"
WAIT_S = 30  # generous: a loaded 2-core machine


def scada(port: int) -> mqtt.Client:
    """The primary host's side of STATE: retained messages on spBv1.0/STATE/<host id>."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-scada")
    client.connect("127.0.0.1", port)
    client.loop_start()
    return client


def say_state(client: mqtt.Client, payload: bytes | dict) -> None:
    data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    client.publish(spb.state_topic(HOST_ID), data, qos=1, retain=True).wait_for_publish(WAIT_S)


def test_the_node_waits_for_its_primary_host_and_ends_its_session_when_it_goes_offline(tmp_path):
    ticks = {"k": 0}

    def values() -> PublishedValues:  # a moving axis: every tick has news
        ticks["k"] += 1
        return PublishedValues(position_m=0.001 * ticks["k"], velocity_mps=0.05, status=StatusBits.VALID,
                               sample_counter=25 * ticks["k"], last_sample_age_ms=2.0)

    historical: list[int] = []

    def keep(message, _arrived_s) -> None:
        if message.topic.kind == "DDATA" and any(m.historical for m in message.metrics):
            historical.append(message.payload.seq)

    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port, group=GROUP, ask_rebirth=False,
                                                   on_message=keep) as view:
        assert view.connected.wait(WAIT_S)
        host = scada(broker.port)

        def node_view():
            with view.lock:
                return view.view.nodes.get((GROUP, "gw1"))

        async def until(predicate, what: str) -> None:
            await wait_for(predicate, WAIT_S, poll_s=0.05, what=what)

        async def main() -> None:
            node = SparkplugNode(SparkplugSettings(port=broker.port, group_id=GROUP, edge_node_id="gw1", qos=1,
                                                   primary_host_id=HOST_ID), values=values, drive_itself=True)
            await node.start()
            try:
                await until(lambda: node.connected, "the node connected")
                await asyncio.sleep(1.0)  # no STATE yet: connected, subscribed, and still not born
                assert node_view() is None and not node.publishing

                say_state(host, {"online": True, "timestamp": 1000})
                await until(lambda: node_view() is not None and node_view().online, "the birth")
                first_bd_seq = node_view().bd_seq
                await until(lambda: node.counters.ddata_sent >= 5, "data after the birth")

                say_state(host, {"online": False, "timestamp": 999})  # older than the online: ignored
                say_state(host, b"not json")  # not a STATE: counted, ignored
                await until(lambda: node.counters.bad_payloads == 1, "the bad STATE counted")
                assert node.publishing and node_view().online and node.counters.host_offline_ends == 0

                say_state(host, {"online": False, "timestamp": 2000})
                await until(lambda: not node_view().online, "the NDEATH of the session")
                assert node.counters.host_offline_ends == 1
                await until(lambda: node.counters.connects == 2, "connected again")
                await asyncio.sleep(1.0)  # the retained STATE says offline: connected and waiting
                assert not node.publishing and node_view().births == 1
                made_while_waiting = node.counters.ddata_made

                say_state(host, {"online": True, "timestamp": 3000})
                await until(lambda: node_view().online and node_view().births == 2, "born again")
                assert node_view().bd_seq == (first_bd_seq + 1) % spb.SEQ_MODULO
                # what was made while the host was away arrives, flagged historical
                await until(lambda: len(historical) > 0, "the data kept while the host was away")
                assert made_while_waiting > 0 and node.counters.dropped == 0
            finally:
                await node.stop()

        try:
            asyncio.run(main())
        finally:
            host.loop_stop()
            host.disconnect()


def test_a_primary_host_id_must_be_a_sparkplug_id(tmp_path):
    from gateway.config import load_config
    from gateway.errors import ConfigError
    path = tmp_path / "gw.toml"
    path.write_text('[mqtt]\nprimary_host_id = "a/b"\n')
    try:
        load_config(path)
    except ConfigError as err:
        assert "primary_host_id" in str(err)
    else:
        raise AssertionError("a primary_host_id with a / was taken")
