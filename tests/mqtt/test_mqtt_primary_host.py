"""Sparkplug 3.0's primary host, against a real mosquitto: an edge node with
`primary_host_id` is born only once the host's retained STATE says online, keeps its data
meanwhile, ends its session (NDEATH, disconnect, connect again) when the host says
offline, ignores a STATE older than the newest (a late death of a host session already
over), and counts a STATE that is not one."""
from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import paho.mqtt.client as mqtt

from drivers import sparkplug_payload as spb
from drivers.published_values import PublishedValues, StatusBits
from drivers.sparkplug_host import FleetListener
from drivers.sparkplug_node import SparkplugNode
from drivers.sparkplug_settings import SparkplugSettings
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


def test_the_fleet_view_as_primary_host_lets_the_node_be_born_and_its_exit_ends_the_session(tmp_path):
    states: list[spb.HostState] = []

    def watch_state(port: int) -> mqtt.Client:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-state-watch")
        client.on_message = lambda _c, _u, m: states.append(spb.decode_state(m.payload))
        client.connect("127.0.0.1", port)
        client.subscribe(spb.state_topic(HOST_ID), qos=1)
        client.loop_start()
        return client

    def values() -> PublishedValues:
        return PublishedValues(position_m=0.1, status=StatusBits.VALID)

    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port, group=GROUP,
                                                   ask_rebirth=False) as observer:
        watcher = watch_state(broker.port)

        def node_view():
            with observer.lock:
                return observer.view.nodes.get((GROUP, "gw1"))

        async def main() -> None:
            node = SparkplugNode(SparkplugSettings(port=broker.port, group_id=GROUP, edge_node_id="gw1",
                                                   primary_host_id=HOST_ID), values=values, drive_itself=True)
            await node.start()
            try:
                await wait_for(lambda: node.connected, WAIT_S, what="the node connected")
                await asyncio.sleep(1.0)
                assert not node.publishing  # no primary host yet
                with FleetListener("127.0.0.1", broker.port, group=GROUP, primary_host_id=HOST_ID) as host:
                    assert host.connected.wait(WAIT_S)
                    await wait_for(lambda: node_view() is not None and node_view().online, WAIT_S,
                                   what="the birth the host's STATE allowed")

                    def host_saw_the_birth() -> bool:  # a second subscriber: its copy may come later
                        with host.lock:
                            seen = host.view.nodes.get((GROUP, "gw1"))
                            return seen is not None and seen.online

                    await wait_for(host_saw_the_birth, WAIT_S, what="the host itself saw the birth")
                # the host's orderly exit: its offline STATE ends the node's session
                await wait_for(lambda: not node_view().online, WAIT_S, what="the node's NDEATH")
                assert node.counters.host_offline_ends == 1
            finally:
                await node.stop()

        try:
            asyncio.run(main())
            # online, then offline with the same timestamp (the connection's), as Sparkplug 3.0 asks
            assert [s.online for s in states] == [True, False]
            assert states[0].timestamp_ms == states[1].timestamp_ms > 0
        finally:
            watcher.loop_stop()
            watcher.disconnect()


def test_adxlgw_fleet_as_primary_host_killed_leaves_its_will_the_offline_state(tmp_path):
    """`adxlgw fleet --primary-host-id` says online; kill -9 of it: the broker publishes its
    will, offline with the timestamp of the online."""
    got: list[spb.HostState] = []
    with Broker(tmp_path) as broker:
        reader = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-will-reader")
        reader.on_message = lambda _c, _u, m: got.append(spb.decode_state(m.payload))
        reader.connect("127.0.0.1", broker.port)
        reader.subscribe(spb.state_topic(HOST_ID), qos=1)
        reader.loop_start()
        fleet = subprocess.Popen([sys.executable, "-m", "gateway.cli", "fleet", "--broker", f"127.0.0.1:{broker.port}",
                                  "--primary-host-id", HOST_ID, "--seconds", "120"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            asyncio.run(wait_for(lambda: got and got[-1].online, WAIT_S, what="the host's STATE online"))
            fleet.kill()
            fleet.wait()
            asyncio.run(wait_for(lambda: not got[-1].online, WAIT_S, what="its will: offline"))
            assert got[-1].timestamp_ms == got[-2].timestamp_ms > 0
        finally:
            if fleet.poll() is None:
                fleet.kill()
                fleet.wait()
            reader.loop_stop()
            reader.disconnect()
