"""A Sparkplug B primary host's view of the fleet: every edge node on a broker, live.

`FleetView` is the state machine, fed (topic, payload, arrival time) and free of I/O:
a node is online from its NBIRTH until the NDEATH whose bdSeq matches that birth (an
NDEATH of an older session is stale and ignored); DDATA update its device's current
values (historical ones are counted, not shown as current); a seq that skips is
counted. `FleetListener` is the MQTT side: it subscribes to ``spBv1.0/<group>/#`` and
asks a node it hears from without having seen its birth for a rebirth (NCMD
"Node Control/Rebirth"), as a primary host does. `adxlgw fleet` prints the view; the
tests and the fleet benchmark read the edge nodes through it.

With `primary_host_id` the listener is a Sparkplug 3.0 *primary host application*, the
one whose STATE the edge nodes configured with that id wait for before their birth
(docs/mqtt.md, "Primary host"): each connection's will is its STATE offline, retained,
with the timestamp of that connection; once subscribed it publishes its STATE online,
retained, with the same timestamp; an orderly exit publishes the offline STATE itself
(the broker drops the will on a clean disconnect). An offline STATE of its own that it
reads while connected (a late will of its previous connection, retained) is answered with
its online STATE again, as the spec asks.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as mqtt

from . import sparkplug_payload as spb

STATE_FLUSH_S = 2.0  # an orderly exit waits this long for its offline STATE to be acknowledged


@dataclass
class DeviceState:
    values: dict[str, Any] = field(default_factory=dict)
    ddata: int = 0  # DDATA received
    historical: int = 0  # of which sent late, flagged historical
    lost: int = 0  # gaps in mqtt/ddata_count: DDATA made by the node that never arrived
    last_count: int | None = None


@dataclass
class NodeState:
    group: str
    node: str
    online: bool = False
    bd_seq: int | None = None
    births: int = 0
    deaths: int = 0
    last_seq: int | None = None
    seq_gaps: int = 0
    last_seen_unix_s: float | None = None
    version: str = ""
    devices: dict[str, DeviceState] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Message:
    """A Sparkplug B message as the view took it."""

    topic: spb.Topic
    payload: Any  # the decoded protobuf Payload
    metrics: list[spb.DecodedMetric]


@dataclass(frozen=True, slots=True)
class FleetRow:
    """One device as `adxlgw fleet` shows it."""

    group: str
    node: str
    device: str
    online: bool
    position_m: float | None
    velocity_mps: float | None
    usable: bool | None
    status: int | None
    last_seen_unix_s: float | None
    births: int
    lost: int
    seq_gaps: int

    def as_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__slots__}


class FleetView:
    def __init__(self) -> None:
        self.nodes: dict[tuple[str, str], NodeState] = {}
        self.bad_payloads = 0

    def node(self, group: str, node: str) -> NodeState:
        key = (group, node)
        if key not in self.nodes:
            self.nodes[key] = NodeState(group, node)
        return self.nodes[key]

    def handle(self, topic: str, data: bytes, arrived_unix_s: float) -> Message | None:
        """Take one message; what it was when it was Sparkplug B, else None."""
        t = spb.parse_topic(topic)
        if t is None or t.kind in ("NCMD", "DCMD"):
            return None
        try:
            payload, metrics = spb.decode(data)
        except ValueError:
            self.bad_payloads += 1
            return None
        self._apply(t, payload, metrics, arrived_unix_s)
        return Message(t, payload, metrics)

    def _apply(self, t: spb.Topic, payload, metrics: list[spb.DecodedMetric], arrived_unix_s: float) -> None:
        n = self.node(t.group, t.node)
        by_name = {m.name: m for m in metrics}
        if t.kind == "NDEATH":
            bd = by_name.get(spb.BDSEQ)
            if bd is not None and bd.value == n.bd_seq:  # else the death of a session already over
                n.online = False
                n.deaths += 1
            return
        n.last_seen_unix_s = arrived_unix_s
        if t.kind == "NBIRTH":
            n.online, n.births, n.last_seq = True, n.births + 1, payload.seq
            n.bd_seq = by_name[spb.BDSEQ].value if spb.BDSEQ in by_name else None
            version = by_name.get("Properties/version")
            n.version = version.value if version is not None else ""
            return
        self._check_seq(n, payload.seq)
        if t.device is None:
            return
        d = n.devices.setdefault(t.device, DeviceState())
        if t.kind == "DBIRTH":
            d.values = {m.name: m.value for m in metrics}
            d.last_count = d.values.get(spb.DDATA_COUNT)
        elif t.kind == "DDATA":
            self._data(d, metrics)
        elif t.kind == "DDEATH":
            d.values = {}
        return

    @staticmethod
    def _check_seq(n: NodeState, seq: int) -> None:
        if n.last_seq is not None and seq != (n.last_seq + 1) % spb.SEQ_MODULO:
            n.seq_gaps += 1
        n.last_seq = seq

    @staticmethod
    def _data(d: DeviceState, metrics: list[spb.DecodedMetric]) -> None:
        d.ddata += 1
        historical = any(m.historical for m in metrics)
        d.historical += historical
        for m in metrics:
            if m.name == spb.DDATA_COUNT:
                if d.last_count is not None and m.value > d.last_count + 1:
                    d.lost += m.value - d.last_count - 1
                d.last_count = m.value if d.last_count is None else max(d.last_count, m.value)
            elif not historical:
                d.values[m.name] = m.value

    def rows(self) -> list[FleetRow]:
        rows = []
        for (group, node), n in sorted(self.nodes.items()):
            for device, d in sorted(n.devices.items()) or [("", DeviceState())]:
                v = d.values
                rows.append(FleetRow(group, node, device, n.online, v.get("position_m"), v.get("velocity_mps"),
                                     v.get("usable"), v.get("status"), n.last_seen_unix_s, n.births, d.lost,
                                     n.seq_gaps))
        return rows


class FleetListener:
    """A FleetView kept up to date from a broker by paho's network thread. `on_message`,
    if given, also sees each message after the view took it (the decoded Message, its
    arrival time) — the benchmark's latency probe."""

    def __init__(self, host: str, port: int, *, group: str = "+", username: str | None = None,
                 password: str | None = None, tls_ca_file: str | None = None, client_id: str = "",
                 persistent: bool = False, ask_rebirth: bool = True, primary_host_id: str | None = None,
                 on_message: Callable[[Message, float], None] | None = None):
        self.view = FleetView()
        self.lock = threading.Lock()
        self.connected = threading.Event()
        self.connect_error: str | None = None
        self._group = group
        self._ask_rebirth = ask_rebirth
        self._rebirth_asked: set[tuple[str, str]] = set()
        self._on_message = on_message
        self._host, self._port = host, port
        # persistent: a session the broker keeps while we are away (the benchmark's host
        # across a broker restart); else a clean one
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
                                   clean_session=not persistent)
        if username is not None:
            self._client.username_pw_set(username, password)
        if tls_ca_file:
            self._client.tls_set(ca_certs=tls_ca_file)
        self._client.reconnect_delay_set(1, 5)
        self._client.on_connect = self._connected
        self._client.on_message = self._message
        self._state_topic = spb.state_topic(primary_host_id) if primary_host_id else None
        self._state_ms = 0  # the timestamp of this connection's STATE (its will and its birth)
        self._closing = False  # our own offline STATE said at exit is not put right
        if self._state_topic is not None:
            self._client.on_pre_connect = self._state_will

    def __enter__(self) -> FleetListener:
        self._client.connect_async(self._host, self._port, keepalive=10)
        self._client.loop_start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._closing = True
        if self._state_topic is not None and self._client.is_connected():
            # an orderly end says the host's death itself: a clean disconnect drops the will
            self._say_state(online=False).wait_for_publish(STATE_FLUSH_S)
        self._client.disconnect()
        self._client.loop_stop()

    def _state_will(self, client, _userdata) -> None:
        # each connection: a new timestamp, which the nodes use to tell this connection's
        # death from a late one of an older connection
        self._state_ms = int(time.time() * 1000)
        client.will_set(self._state_topic, spb.encode_state(spb.HostState(False, self._state_ms)), qos=1,
                        retain=True)

    def _say_state(self, *, online: bool) -> mqtt.MQTTMessageInfo:
        return self._client.publish(self._state_topic, spb.encode_state(spb.HostState(online, self._state_ms)),
                                    qos=1, retain=True)

    def _connected(self, client, _userdata, flags, reason, _properties) -> None:
        if reason.is_failure:
            self.connect_error = str(reason)
            return
        subscriptions = [(f"{spb.NAMESPACE}/{self._group}/#", 1)]
        if self._state_topic is not None:
            subscriptions.append((self._state_topic, 1))
        client.subscribe(subscriptions)
        if self._state_topic is not None:  # after the subscription: no birth the host could miss
            self._say_state(online=True)
        self.connected.set()

    def _message(self, client, _userdata, message: mqtt.MQTTMessage) -> None:
        arrived = time.time()
        if message.topic == self._state_topic:
            self._own_state(message.payload)
            return
        with self.lock:
            handled = self.view.handle(message.topic, message.payload, arrived)
            if handled is None:
                return
            topic = handled.topic
            node = self.view.nodes[(topic.group, topic.node)]
            if self._ask_rebirth and node.births == 0 and topic.kind != "NDEATH":
                key = (topic.group, topic.node)
                if key not in self._rebirth_asked:  # once: a node that never answers is not spammed
                    self._rebirth_asked.add(key)
                    client.publish(spb.node_topic(topic.group, "NCMD", topic.node), write_true(spb.REBIRTH), qos=0)
        if self._on_message is not None:
            self._on_message(handled, arrived)

    def _own_state(self, data: bytes) -> None:
        """Our own STATE as the broker has it: offline while we are connected (our will
        from a connection the broker has not yet seen die, or someone else's) is put right."""
        try:
            state = spb.decode_state(data)
        except ValueError:
            state = None
        if (state is None or not state.online) and not self._closing:
            self._say_state(online=True)

    def rows(self) -> list[FleetRow]:
        with self.lock:
            return self.view.rows()


def write_true(metric_name: str) -> bytes:
    """An NCMD/DCMD payload that writes true to one metric: "Node Control/Rebirth", or a
    command such as "Commands/TARE"."""
    p = spb.Payload(timestamp=int(time.time() * 1000))
    m = p.metrics.add()
    m.name = metric_name
    m.datatype = int(spb.DataType.BOOLEAN)
    m.boolean_value = True
    return p.SerializeToString()
