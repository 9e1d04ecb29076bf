"""The QoS 0 DDATA the edge node writes to the socket itself (without paho's publish):
MQTT 3.1.1 PUBLISH packets that a real mosquitto takes and passes on byte for byte, and
paho's path whenever paho has bytes of its own waiting (its and these must not interleave)."""
from __future__ import annotations

import asyncio
import threading

import paho.mqtt.client as mqtt
import pytest

from drivers import sparkplug_payload as spb
from drivers.mqtt_packet import mqtt_varint, qos0_publish_packet, topic_field
from drivers.published_values import PublishedValues, StatusBits
from drivers.sparkplug_node import SparkplugNode
from drivers.sparkplug_settings import SparkplugSettings
from testing.mqtt_helpers import Broker
from tests.daemon_helpers import wait_for

WAIT_S = 30  # generous: a loaded 2-core machine


@pytest.mark.parametrize(("n", "encoded"), [(0, b"\x00"), (127, b"\x7f"), (128, b"\x80\x01"),
                                            (16_383, b"\xff\x7f"), (16_384, b"\x80\x80\x01"),
                                            (268_435_455, b"\xff\xff\xff\x7f")])
def test_the_remaining_length_is_the_specs_own_examples(n, encoded):
    assert mqtt_varint(n) == encoded  # MQTT 3.1.1, table 2.4


def test_a_qos0_publish_packet_is_header_length_topic_payload():
    assert qos0_publish_packet(topic_field("a/b"), b"xy") == b"\x30\x07\x00\x03a/bxy"


def subscriber(port: int, topic: str) -> tuple[mqtt.Client, list[bytes], threading.Event]:
    got: list[bytes] = []
    ready = threading.Event()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-direct-sub")
    client.on_message = lambda _c, _u, m: got.append(m.payload)
    client.on_subscribe = lambda *_: ready.set()
    client.connect("127.0.0.1", port)
    client.subscribe(topic, qos=0)
    client.loop_start()
    return client, got, ready


@pytest.mark.parametrize("payload_size", [40, 300])  # a 1-byte and a 2-byte remaining length
def test_the_broker_passes_on_a_directly_written_publish_byte_for_byte(tmp_path, payload_size):
    payload = bytes(range(256)) * 2
    payload = payload[:payload_size]
    topic = spb.device_topic("g", "DDATA", "n", "axis")
    with Broker(tmp_path) as broker:
        sub, got, ready = subscriber(broker.port, topic)
        try:
            assert ready.wait(WAIT_S)
            pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-direct-pub", protocol=mqtt.MQTTv311)
            pub.connect("127.0.0.1", broker.port)
            pub.loop_read()  # the CONNACK
            pub.socket().send(qos0_publish_packet(topic_field(topic), payload))
            pub.socket().send(qos0_publish_packet(topic_field(topic), payload[::-1]))
            asyncio.run(wait_for(lambda: len(got) == 2, WAIT_S, what="both messages"))
            assert got == [payload, payload[::-1]]
            pub.disconnect()
        finally:
            sub.loop_stop()
            sub.disconnect()


def test_ddata_go_direct_at_qos0_and_through_paho_while_paho_has_bytes_waiting(tmp_path):
    ticks = {"k": 0}

    def values() -> PublishedValues:  # a moving axis: every tick has news
        ticks["k"] += 1
        return PublishedValues(position_m=0.001 * ticks["k"], status=StatusBits.VALID, sample_counter=ticks["k"])

    async def run(port: int, sub_got: list[bytes]) -> tuple[int, int]:
        node = SparkplugNode(SparkplugSettings(port=port, group_id="g", edge_node_id="n", rate_hz=50.0),
                             values=values, drive_itself=True)
        direct_sends = {"n": 0}
        real_send_direct = node._send_direct

        def counting(payload: bytes) -> bool:
            client = node._client
            if node.publishing and not client.want_write():
                direct_sends["n"] += 1
            return real_send_direct(payload)

        node._send_direct = counting
        through_paho: list[str] = []
        real_publish = node._publish

        def paho_publish(topic: str, payload: bytes) -> bool:
            through_paho.append(topic)
            return real_publish(topic, payload)

        node._publish = paho_publish
        await node.start()
        try:
            await wait_for(lambda: len(sub_got) >= 10, WAIT_S, what="10 DDATA")
            # paho holds a packet of its own (a ping it queued and could not write yet): the
            # next DDATA must queue behind it, through paho
            node._client._out_packet.append({"command": mqtt.PINGREQ, "mid": 0, "qos": 0, "pos": 0,
                                             "to_process": 2, "packet": b"\xc0\x00", "info": None})
            published, before = node.counters.ddata_sent, len(through_paho)
            await wait_for(lambda: node.counters.ddata_sent > published, WAIT_S, what="a DDATA behind the ping")
            assert through_paho[before:] == [node.topics["DDATA"]]
            received = len(sub_got)
            await wait_for(lambda: len(sub_got) > received, WAIT_S, what="it at the subscriber")
            return direct_sends["n"], received
        finally:
            await node.stop()

    with Broker(tmp_path) as broker:
        sub, got, ready = subscriber(broker.port, spb.device_topic("g", "DDATA", "n", "axis"))
        try:
            assert ready.wait(WAIT_S)
            direct, received = asyncio.run(run(broker.port, got))
            assert direct >= 10
            assert received >= 10
            counts = [dict((m.name, m.value) for m in spb.decode(p)[1])[spb.DDATA_COUNT] for p in got]
            assert counts == sorted(counts)
        finally:
            sub.loop_stop()
            sub.disconnect()
