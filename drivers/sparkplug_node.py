"""The gateway as a Sparkplug B edge node on an MQTT broker (paho-mqtt 2.x).

One node per gateway, one device (the axis). paho-mqtt runs without a thread of its
own: the node does its socket work from `poll()`, which the daemon calls at every
publish (once per batch of board samples, and every quiet tick while the board is
silent) and which does anything only once per 1/rate_hz. So MQTT adds no wakeup of
its own to the daemon — on a VM each wakeup costs about as much as the MQTT work
itself (docs/mqtt.md, "Measured"). A node without such a caller (the benchmark's
simulated ones) drives itself with `drive_itself=True`.

- The sample path never waits for MQTT: a poll that is not due is one comparison; a
  due one reads what the broker sent (acknowledgements, commands), sends one DDATA with
  the metrics that changed (report by exception) and writes it to the non-blocking
  socket; what the kernel does not take now stays in paho's queue for the next poll.
  Only the TCP connect, which can take seconds, runs in a worker thread.
- While the broker is away the DDATA wait in a bounded backlog (BACKLOG_S of them,
  drivers/sparkplug_settings.py);
  when it is full the oldest is dropped and counted (`counters.dropped`, the Modbus
  register MQTT_DROPPED, the metric mqtt/dropped). After the rebirth they go out
  flagged `is_historical`, so that no host takes them for current values.
- Every MQTT CONNECT carries the NDEATH as its will, with the session's bdSeq (set in
  paho's pre-connect hook, so each reconnect gets the next one); the broker publishes
  it when the node dies without a word (kill -9, a cut cable: at once when the TCP
  connection closes, else after 1.5 × keepalive_s). An orderly stop publishes it itself.
- Each connection: subscribe to NCMD/DCMD, then NBIRTH (seq 0) and DBIRTH. An NCMD
  "Node Control/Rebirth" repeats the births; a DCMD carries commands, refused and
  counted unless commands_enabled (as Modbus and CAN refuse them).
- With a primary host (Sparkplug 3.0, `primary_host_id`): each connection also
  subscribes to the host's STATE (retained by the broker) and is born only once the host
  says online=true; meanwhile the DDATA wait in the backlog as while the broker is away.
  An offline STATE no older than the last one (the timestamp tells a late death of the
  host's previous session from the current one) ends a born session: NDEATH, disconnect,
  and the connection starts over (with one broker it then waits for the host there).
- A broker that is missing or refuses the node: one log line per kind of failure,
  reconnects with back-off (RECONNECT_MIN_S doubling to RECONNECT_MAX_S); the other
  wires never notice.
"""
from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import socket
import ssl
import time
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as mqtt

from . import sparkplug_payload as spb
from .mqtt_packet import MAX_DIRECT_PACKET, qos0_publish_packet, topic_field
from .published_values import Command, CommandCallback, ValuesSource, current
from .sparkplug_settings import NodeCounters, SparkplugError, SparkplugSettings, tls_ca_problem

log = logging.getLogger("adxlgw.mqtt")

RECONNECT_MIN_S = 1  # paho takes whole seconds
RECONNECT_MAX_S = 30
#: paho's own queue of QoS 1 messages not yet acknowledged (bounded: a broker that
#: accepts the connection but stops acknowledging must not grow it without end)
MAX_PAHO_QUEUE = 1000
DEATH_FLUSH_S = 1.0  # an orderly stop waits this long for its NDEATH to leave
#: How often a poll reads the socket (acknowledgements, commands, the keep-alive's answer):
#: each read is several system calls (paho reads a packet's header byte by byte), on a VM
#: ~40 µs each; a command waits at most this long, and QoS 1 acknowledgements are read
#: in batches (paho keeps up to 20 messages in flight).
READ_EVERY_S = 0.25
REFUSAL_LOG_EVERY_S = 10.0  # refused commands: one log line per this interval at most


class SparkplugNode:
    """Use: `await node.start()`, `await node.stop()` (idempotent); `connected`,
    `counters` for the status surfaces."""

    def __init__(self, settings: SparkplugSettings, *, values: ValuesSource,
                 on_command: CommandCallback | None = None, version: str = "",
                 wall_clock: Callable[[], float] = time.time, drive_itself: bool = False,
                 first_bd_seq: int = 0):
        self.settings = settings
        self._values = values
        self._on_command = on_command
        self._version = version
        self._wall_clock = wall_clock
        self.counters = NodeCounters()
        self.connected = False
        self._born = False
        self._seq = 0
        # each CONNECT takes the next; a node that replaces another (a reload) goes on from its
        # last, so that a late NDEATH of the old session never matches the new birth
        self._bd_seq = (first_bd_seq - 1) % spb.SEQ_MODULO
        self._last_reading: spb.Reading | None = None  # what the last birth or DDATA carried
        self._dropped_sent = 0  # the mqtt/dropped last sent
        #: DDATA made while not born: (timestamp ms, the reading, its mqtt/ddata_count)
        self._backlog: collections.deque[tuple[int, spb.Reading, int]] = collections.deque()
        self._drive_itself = drive_itself
        self._period_s = 1.0 / settings.rate_hz
        self._due_s = 0.0  # time.monotonic() of the next due poll
        self._read_due_s = 0.0  # and of the next read of the socket
        self._refusal_said_s = -REFUSAL_LOG_EVERY_S
        self._client: mqtt.Client | None = None
        self._socket_ready = False  # connected at the TCP level, not inside a connect attempt
        self._reconnect_now = asyncio.Event()
        self._tasks: list[asyncio.Task] = []
        self._failure_said: str | None = None  # the last failure logged (said once until it changes)
        self._host_online = False  # the primary host said online=true in this connection
        self._host_state_ms: int | None = None  # timestamp of the newest valid STATE (kept across connections)
        s = settings
        self.topics = {
            "NBIRTH": spb.node_topic(s.group_id, "NBIRTH", s.edge_node_id),
            "NDEATH": spb.node_topic(s.group_id, "NDEATH", s.edge_node_id),
            "NCMD": spb.node_topic(s.group_id, "NCMD", s.edge_node_id),
            "DBIRTH": spb.device_topic(s.group_id, "DBIRTH", s.edge_node_id, s.device_id),
            "DDATA": spb.device_topic(s.group_id, "DDATA", s.edge_node_id, s.device_id),
            "DCMD": spb.device_topic(s.group_id, "DCMD", s.edge_node_id, s.device_id),
        }
        if s.primary_host_id:
            self.topics["STATE"] = spb.state_topic(s.primary_host_id)
        self._ddata_topic_field = topic_field(self.topics["DDATA"])
        # QoS 0 DDATA go straight to the socket (see _send_direct); not over TLS, whose
        # non-blocking writes can be cut short (SSLWantWriteError) and are paho's to resume
        self._direct = settings.qos == 0 and not settings.tls_ca_file

    @property
    def bd_seq(self) -> int:
        """The current (or last) session's bdSeq."""
        return self._bd_seq

    @property
    def publishing(self) -> bool:
        """Connected and born: a host sees this node's data now."""
        return self.connected and self._born

    @property
    def where(self) -> str:
        return f"{self.settings.host}:{self.settings.port}"

    # ------------------------------------------------------------ lifecycle --
    async def start(self) -> None:
        s = self.settings
        # MQTT 3.1.1 said explicitly: the QoS 0 DDATA written directly (_send_direct) are its packets
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"spb-{s.group_id}-{s.edge_node_id}",
                             clean_session=True, protocol=mqtt.MQTTv311)  # Sparkplug: edge nodes start clean sessions
        if s.username is not None:
            client.username_pw_set(s.username, s.password)
        if s.tls_ca_file:
            problem = tls_ca_problem(s.tls_ca_file)  # (checked before start too; the file may have changed since)
            if problem:
                raise SparkplugError(f"MQTT TLS CA file {s.tls_ca_file}: {problem}")
            client.tls_set(ca_certs=s.tls_ca_file, tls_version=ssl.PROTOCOL_TLS_CLIENT)
        client.max_queued_messages_set(MAX_PAHO_QUEUE)
        client.on_pre_connect = self._pre_connect
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        # host, port and keepalive for reconnect(); nothing is sent yet
        client.connect_async(s.host, s.port, keepalive=s.keepalive_s)
        self._client = client
        self._tasks.append(asyncio.create_task(self._keep_connected(), name="mqtt-connect"))
        if self._drive_itself:
            self._tasks.append(asyncio.create_task(self._drive(), name="mqtt-poll"))
        log.info("MQTT edge node %s/%s connecting to %s", s.group_id, s.edge_node_id, self.where)

    async def stop(self) -> None:
        client, self._client = self._client, None
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if client is None:
            return
        if self.connected and self._socket_ready:
            # an orderly end: say the death ourselves (the broker drops the will on a clean disconnect)
            info = client.publish(self.topics["NDEATH"], spb.node_death(self._bd_seq), qos=1)
            await self._flush(client, info, DEATH_FLUSH_S)
            client.disconnect()
        self.connected = self._born = self._socket_ready = False
        sock = client.socket()
        if sock is not None:
            sock.close()

    @staticmethod
    async def _flush(client: mqtt.Client, info: mqtt.MQTTMessageInfo, timeout_s: float) -> None:
        """Until the broker acknowledged `info`'s message (or timeout)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while loop.time() < deadline and client.socket() is not None and not info.is_published():
            client.loop_write()
            client.loop_read()
            await asyncio.sleep(0.01)

    async def _drive(self) -> None:
        """For a node without a daemon calling poll(): poll at the rate."""
        while True:
            await asyncio.sleep(self._period_s)
            self.poll()

    async def _keep_connected(self) -> None:
        """Connect, and again after each loss, with back-off; the TCP connect (and TLS
        handshake) in a worker thread, everything after it in polls."""
        delay_s = RECONNECT_MIN_S
        while True:
            client = self._client
            if client is None:
                return
            self._socket_ready = False
            self._reconnect_now.clear()
            try:
                await asyncio.to_thread(client.reconnect)
            except (OSError, ssl.SSLError) as err:
                self._failed(f"cannot reach the broker ({err.strerror or err})"
                             if isinstance(err, OSError) else f"TLS: {err}")
            else:
                self._socket_ready = True
                self._due_s = 0.0  # the CONNACK is read at the next poll
                await self._reconnect_now.wait()  # until the connection ends
                if self.counters.connects and self._failure_said is None:
                    delay_s = RECONNECT_MIN_S  # it was up: come back soon
            await asyncio.sleep(delay_s)
            delay_s = min(2 * delay_s, RECONNECT_MAX_S)

    # ------------------------------------------------------------- the poll --
    def poll(self) -> None:
        """Once per 1/rate_hz (else nothing): the broker's news, one DDATA, the socket
        written, keep-alive kept. Called from the event loop, never blocks."""
        now = time.monotonic()
        if now < self._due_s:
            return
        self._due_s = max(self._due_s + self._period_s, now) if self._due_s else now + self._period_s
        client = self._client
        if client is None:
            return
        read_now = self._socket_ready and (now >= self._read_due_s or not self.connected)
        if read_now:
            self._read_due_s = now + READ_EVERY_S
            client.loop_read()  # every packet waiting; callbacks run here
        try:
            self._tick()
        except Exception:  # a bug: say it, keep the node (and the daemon) alive
            log.exception("MQTT data tick failed")
        if self._socket_ready:
            if client.want_write():  # (a publish writes at once; this is what the kernel did not take)
                client.loop_write()
            if read_now:  # keep-alive: a ping due, a ping unanswered — seconds, checked with the reads
                client.loop_misc()

    # ------------------------------------------------ paho's callbacks (in polls) --
    def _pre_connect(self, client: mqtt.Client, _userdata: Any) -> None:
        # a new session each CONNECT: the next bdSeq, and the will that ends this session
        self._bd_seq = (self._bd_seq + 1) % spb.SEQ_MODULO
        client.will_set(self.topics["NDEATH"], spb.node_death(self._bd_seq), qos=1, retain=False)

    def _on_connect(self, client, _userdata, flags, reason, _properties) -> None:
        self._connected(reason.is_failure, str(reason))

    def _on_disconnect(self, client, _userdata, flags, reason, _properties) -> None:
        self._socket_ready = False
        self._reconnect_now.set()
        self._disconnected(str(reason))

    def _on_message(self, client, _userdata, message: mqtt.MQTTMessage) -> None:
        self._message(message.topic, message.payload)

    # ------------------------------------------------------------- Sparkplug --
    def _failed(self, why: str) -> None:
        if self._client is None:
            return
        if self._failure_said != why:
            self._failure_said = why
            log.error("MQTT broker %s: %s; retrying with back-off up to %d s (Modbus and CAN keep serving)",
                      self.where, why, RECONNECT_MAX_S)
        else:
            log.debug("MQTT broker %s: %s", self.where, why)

    def _connected(self, failed: bool, reason: str) -> None:
        if self._client is None:
            return
        if failed:
            self._failed(f"refused the connection: {reason}")
            return
        self.counters.connects += 1
        self.connected = True
        if self._failure_said is not None or self.counters.connects > 1:
            log.info("MQTT connected to %s again (session bdSeq %d)", self.where, self._bd_seq)
        else:
            log.info("MQTT connected to %s (session bdSeq %d)", self.where, self._bd_seq)
        self._failure_said = None
        self._host_online = False
        subscriptions = [(self.topics["NCMD"], 1), (self.topics["DCMD"], 1)]
        if "STATE" in self.topics:  # the broker retains the host's last STATE: it comes at once if there is one
            subscriptions.append((self.topics["STATE"], 1))
            log.info("MQTT waiting for primary host %s to be online before birth", self.settings.primary_host_id)
        self._client.subscribe(subscriptions)
        if "STATE" not in self.topics:
            self._be_born()

    def _be_born(self) -> None:
        self._birth()
        self._send_backlog()

    def _disconnected(self, reason: str) -> None:
        was = self.connected
        self.connected = self._born = False
        if self._client is not None and was:
            log.warning("MQTT connection to %s lost (%s); reconnecting", self.where, reason)

    def _next_seq(self) -> int:
        seq, self._seq = self._seq, (self._seq + 1) % spb.SEQ_MODULO
        return seq

    def _now_ms(self) -> int:
        return int(self._wall_clock() * 1000)

    def _birth(self) -> None:
        """NBIRTH (seq 0) and DBIRTH with every metric, as of now."""
        now_ms = self._now_ms()
        self._seq = 0
        self._publish(self.topics["NBIRTH"], spb.node_birth(now_ms, self._next_seq(), self._bd_seq, self._version))
        reading = self._reading()
        row = spb.row_of(reading)
        row[spb.DDATA_COUNT] = self.counters.ddata_made
        row[spb.MQTT_DROPPED] = self._dropped_sent = self.counters.dropped
        self._publish(self.topics["DBIRTH"], spb.device_birth(now_ms, self._next_seq(), row))
        self._last_reading = reading
        self._born = True
        self.counters.births += 1

    def _reading(self) -> spb.Reading:
        """The device metrics of the newest snapshot, the node's own counters aside."""
        return spb.device_reading(current(self._values))

    def _publish(self, topic: str, payload: bytes) -> bool:
        info = self._client.publish(topic, payload, qos=self.settings.qos)
        if info.rc == mqtt.MQTT_ERR_QUEUE_SIZE:
            self.counters.dropped += 1
            return False
        return True

    def _tick(self) -> None:
        """One rate period: a DDATA with what changed, or into the backlog while away."""
        reading = self._reading()
        if not self._born:
            self._keep(reading)
            return
        previous = self._last_reading  # (set by the birth)
        if reading == previous:  # report by exception: nothing changed, nothing sent
            return
        counters = self.counters
        counters.ddata_made += 1
        dropped = None
        if counters.dropped != self._dropped_sent:
            dropped = self._dropped_sent = counters.dropped
        payload = spb.changed_device_data(self._now_ms(), self._next_seq(), previous, reading,
                                          counters.ddata_made, dropped)
        if self._send_direct(payload) if self._direct else self._publish(self.topics["DDATA"], payload):
            counters.ddata_sent += 1
        self._last_reading = reading

    def _keep(self, reading: spb.Reading) -> None:
        """Not born (the broker away, or the primary host): a reading that changed waits in
        the backlog, the oldest dropped and counted when it is full."""
        previous = self._backlog[-1][1] if self._backlog else self._last_reading
        if previous == reading:
            return
        counters = self.counters
        counters.ddata_made += 1
        if len(self._backlog) >= self.settings.backlog_len:
            self._backlog.popleft()
            counters.dropped += 1
        self._backlog.append((self._now_ms(), reading, counters.ddata_made))

    def _send_direct(self, payload: bytes) -> bool:
        """A current QoS 0 DDATA written to the socket as one MQTT PUBLISH packet, without
        paho's publish: that is some 60 Python calls (a message-info object with its lock,
        the property and topic checks, its queue) for a message that at QoS 0 has nothing
        to track — measured, the largest part of a DDATA's cost (docs/decisions/0152).
        Only when paho has nothing of its own waiting to be written (else its bytes and
        these would interleave) and the packet fits one TCP segment (MAX_DIRECT_PACKET);
        else through paho. A full socket buffer (the broker stopped reading) drops it and
        counts it, as paho's full queue does. paho's keep-alive does not see these
        writes and pings every keepalive_s: a 2-byte packet, harmless."""
        client = self._client
        sock = client.socket()
        packet = qos0_publish_packet(self._ddata_topic_field, payload)
        if sock is None or not self._socket_ready or client.want_write() or len(packet) > MAX_DIRECT_PACKET:
            return self._publish(self.topics["DDATA"], payload)
        try:
            sent = sock.send(packet)
        except OSError:  # the buffer full (BlockingIOError), or the connection going (paho's next read says so)
            self.counters.dropped += 1
            return False
        if sent != len(packet):  # the buffer ran out inside it: the stream is cut, so start over
            log.error("MQTT: a %d-byte packet written only in part (%d); reconnecting", len(packet), sent)
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)  # paho's next read sees the end: reconnect, rebirth
        return True

    def _send_backlog(self) -> None:
        """What was made while the broker was away, after the births, flagged historical."""
        previous: spb.Reading | None = None
        while self._backlog and self._born:
            stamp_ms, reading, count = self._backlog.popleft()
            changed = spb.reading_changes(previous, reading)
            changed[spb.DDATA_COUNT] = count
            previous = reading
            if self._publish(self.topics["DDATA"], spb.device_data(stamp_ms, self._next_seq(), changed,
                                                                  historical=True)):
                self.counters.ddata_sent += 1

    # ------------------------------------------------------------- commands --
    def _message(self, topic: str, data: bytes) -> None:
        if self._client is None:
            return
        if topic == self.topics.get("STATE"):
            self._host_state(data)
            return
        try:
            _, metrics = spb.decode(data)
        except ValueError as err:
            self.counters.bad_payloads += 1
            log.warning("MQTT %s: %s", topic, err)
            return
        if topic == self.topics["NCMD"]:
            if any(m.name == spb.REBIRTH and m.value for m in metrics):
                log.info("MQTT rebirth asked (NCMD)")
                if self._born:  # (not while waiting for the primary host)
                    self._birth()
            return
        if topic == self.topics["DCMD"]:
            for m in metrics:
                command = spb.COMMANDS.get(m.name)
                if command is not None and m.value:
                    self._command(command, topic)

    def _host_state(self, data: bytes) -> None:
        """The primary host's STATE: online → born (once per connection); offline → a born
        session ends (NDEATH, disconnect, start over). Older than the newest seen: a late
        message of a host session already over, ignored."""
        try:
            state = spb.decode_state(data)
        except ValueError as err:
            self.counters.bad_payloads += 1
            log.warning("MQTT %s: %s", self.topics["STATE"], err)
            return
        if self._host_state_ms is not None and state.timestamp_ms < self._host_state_ms:
            log.info("MQTT primary host %s: a STATE older than the last one, ignored", self.settings.primary_host_id)
            return
        self._host_state_ms = state.timestamp_ms
        host = self.settings.primary_host_id
        if state.online:
            if self.connected and not self._host_online:
                self._host_online = True
                log.info("MQTT primary host %s is online: birth", host)
                self._be_born()
            return
        self._host_online = False
        if not self._born:
            log.info("MQTT primary host %s is offline: waiting for it before birth", host)
            return
        log.warning("MQTT primary host %s went offline: NDEATH, disconnect, connect again", host)
        self.counters.host_offline_ends += 1
        self._born = False  # the data wait in the backlog from now on
        self._client.publish(self.topics["NDEATH"], spb.node_death(self._bd_seq), qos=1)
        self._client.disconnect()  # (sent with the NDEATH at this poll's write; then the reconnect loop)

    def _command(self, command: Command, topic: str) -> None:
        if not self.settings.commands_enabled or self._on_command is None:
            self.counters.commands_refused += 1
            now = time.monotonic()
            if now - self._refusal_said_s >= REFUSAL_LOG_EVERY_S:  # a host that insists: bounded log
                self._refusal_said_s = now
                log.warning("MQTT command %s refused: mqtt.commands_enabled is false (%d refused so far)",
                            command.name, self.counters.commands_refused)
            return
        if self._on_command(command, f"mqtt:{topic}"):
            self.counters.commands_done += 1
        else:
            self.counters.commands_refused += 1


