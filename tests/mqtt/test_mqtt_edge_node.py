"""The Sparkplug B edge node against a real mosquitto on a free loopback port, read by
the fleet host view (drivers/sparkplug_host.py) and decoded with the .proto: births,
data by exception with aliases, the death as the will (kill -9) and said on a stop, a
rebirth after a broker restart and on request, commands refused unless enabled, a
bridged edge broker, and a broker that is missing or refuses the node while Modbus
and CAN keep serving."""
from __future__ import annotations

import asyncio
import logging
import signal
import subprocess
import sys
import time

import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers import sparkplug_payload as spb
from drivers.published_values import StatusExtBits
from drivers.sparkplug_host import FleetListener, write_true
from testing.mqtt_helpers import Broker, free_port
from tests.daemon_helpers import gateway_config, read_inputs, running_gateway, wait_for

GROUP = "plant-test"
WAIT_S = 30  # generous: a loaded 2-core machine


def run(coro):
    return asyncio.run(coro)


def mqtt_config(tmp_path, broker_port: int, node: str = "gw1", **mqtt):
    section = {"enabled": True, "port": broker_port, "group_id": GROUP, "edge_node_id": node, "rate_hz": 20.0,
               **mqtt}
    # stale only after 2 s: a loaded machine must not make the tare decline (STALE) by chance
    return gateway_config(tmp_path, "emulated", mqtt=section, serial={"stale_after_ms": 2000, "lost_after_ms": 5000})


def node_of(listener: FleetListener, node: str = "gw1"):
    with listener.lock:
        return listener.view.nodes.get((GROUP, node))


def device_values(listener: FleetListener, node: str = "gw1") -> dict:
    n = node_of(listener, node)
    with listener.lock:
        return dict(n.devices["axis"].values) if n is not None and "axis" in n.devices else {}


async def until(predicate, what: str, timeout_s: float = WAIT_S):
    await wait_for(predicate, timeout_s, poll_s=0.05, what=what)


def test_births_data_by_exception_and_the_death_on_a_stop(tmp_path):
    raw: list[tuple[spb.Topic, bytes]] = []
    def keep(message, _arrived_s):
        raw.append((message.topic, message.payload.SerializeToString()))

    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port, on_message=keep) as host:
        assert host.connected.wait(WAIT_S)
        cfg = mqtt_config(tmp_path, broker.port)

        async def scenario():
            async with running_gateway(cfg) as gw:
                await until(lambda: node_of(host) is not None and node_of(host).online, "NBIRTH")
                await until(lambda: device_values(host).get("sample_counter", 0) > 0, "DDATA with samples")
                assert gw.mqtt.connected and gw.mqtt.counters.births == 1
                regs = None
                client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
                await client.connect()
                regs = await read_inputs(client)
                client.close()
                assert StatusExtBits.MQTT_DOWN not in StatusExtBits(regs["STATUS_EXT"])
                assert regs["MQTT_DROPPED"] == 0
                # a PLC on Modbus, a CAN tool and a Sparkplug host read the same gateway at once
                await until(lambda: gw.can.counters.frames_sent > 5, "CAN frames")
            await until(lambda: not node_of(host).online, "NDEATH after an orderly stop")

        run(scenario())
    kinds = [t.kind for t, _ in raw]
    assert kinds[:2] == ["NBIRTH", "DBIRTH"] and "DDATA" in kinds and kinds[-1] == "NDEATH"
    nbirth = spb.decode(raw[0][1])
    assert nbirth[0].seq == 0
    assert {m.name for m in nbirth[1]} == {m.name for m in spb.NODE_METRICS}
    dbirth_payload, dbirth = spb.decode(raw[1][1])
    assert dbirth_payload.seq == 1
    assert {m.name for m in dbirth} == {m.name for m in spb.DEVICE_METRICS}
    assert all(m.name and m.alias == spb.ALIASES[m.name] for m in dbirth_payload.metrics)
    # DDATA: aliases only, the changed metrics only, seq going on modulo 256
    seqs = [spb.decode(p)[0].seq for t, p in raw if t.kind in ("DBIRTH", "DDATA")]
    assert all(b == (a + 1) % 256 for a, b in zip(seqs, seqs[1:], strict=False))
    ddata = [spb.Payload.FromString(p) for t, p in raw if t.kind == "DDATA"]
    assert all(not m.name and m.alias for d in ddata for m in d.metrics)
    assert all(len(d.metrics) < len(spb.DEVICE_METRICS) for d in ddata)
    death = spb.decode(raw[-1][1])[1]
    assert [(m.name, m.value) for m in death] == [(spb.BDSEQ, node_of(host).bd_seq)]


def test_kill_9_of_the_daemon_gives_its_ndeath(tmp_path):
    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port) as host:
        assert host.connected.wait(WAIT_S)
        config = tmp_path / "gw.toml"
        config.write_text(
            f'[serial]\nport = "emulated"\n[modbus]\nport = 0\n[can]\nenabled = false\n'
            f'[state]\npath = "{tmp_path / "state.json"}"\n'
            f'[mqtt]\nenabled = true\nport = {broker.port}\ngroup_id = "{GROUP}"\nedge_node_id = "killed"\n')
        proc = subprocess.Popen([sys.executable, "-m", "gateway.cli", "run", "--config", str(config)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            while not (node_of(host, "killed") is not None and node_of(host, "killed").online):
                assert proc.poll() is None, proc.stderr.read()
                assert time.monotonic() < deadline, "no NBIRTH from adxlgw run"
                time.sleep(0.1)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
            deadline = time.monotonic() + WAIT_S
            while node_of(host, "killed").online:
                assert time.monotonic() < deadline, "no NDEATH after kill -9"
                time.sleep(0.1)
            assert node_of(host, "killed").deaths == 1
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()


def test_a_broker_restart_ends_in_a_rebirth_with_the_next_bdseq(tmp_path):
    # as a plant runs it: a broker that keeps its sessions (persistence), a host with a
    # persistent session, so what the node sends before the host is back waits for it
    broker = Broker(tmp_path, persistence=True).start()
    host = FleetListener("127.0.0.1", broker.port, client_id="test-host", persistent=True)
    try:
        host.__enter__()
        assert host.connected.wait(WAIT_S)
        # QoS 1: the broker keeps what the node sends for the host while the host is not back
        cfg = mqtt_config(tmp_path, broker.port, qos=1)

        def historical() -> int:
            n = node_of(host)
            with host.lock:
                return n.devices["axis"].historical if n is not None and "axis" in n.devices else 0

        async def scenario():
            async with running_gateway(cfg) as gw:
                await until(lambda: node_of(host) is not None and node_of(host).online, "the first birth")
                first_bd = node_of(host).bd_seq
                broker.stop()
                await until(lambda: not gw.mqtt.connected, "the loss seen")
                await until(lambda: StatusExtBits.MQTT_DOWN in gw.fresh_values().status_ext, "MQTT_DOWN")
                await asyncio.sleep(0.5)  # data made meanwhile wait in the backlog
                broker.start()
                await until(lambda: gw.mqtt.counters.births >= 2, "the rebirth")
                await until(lambda: node_of(host).bd_seq != first_bd and node_of(host).online,
                            "the host sees the node born again")
                assert node_of(host).bd_seq == gw.mqtt._bd_seq != first_bd  # one more per CONNECT tried
                await until(lambda: StatusExtBits.MQTT_DOWN not in gw.fresh_values().status_ext,
                            "MQTT_DOWN cleared")
                await until(lambda: historical() > 0, "the backlog sent, flagged historical")

        run(scenario())
    finally:
        host.__exit__()
        broker.stop()


def test_a_rebirth_on_request_and_commands_refused_unless_enabled(tmp_path):
    import paho.mqtt.client as mqtt

    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port) as host:
        assert host.connected.wait(WAIT_S)
        sender = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        sender.connect("127.0.0.1", broker.port)
        sender.loop_start()
        dcmd = spb.device_topic(GROUP, "DCMD", "gw1", "axis")

        async def scenario(commands_enabled: bool):
            cfg = mqtt_config(tmp_path, broker.port, commands_enabled=commands_enabled)
            heard_before = node_of(host).births if node_of(host) is not None else 0
            async with running_gateway(cfg) as gw:
                # the birth heard by a host: the broker has the node's subscriptions (sent before it)
                await until(lambda: node_of(host) is not None and node_of(host).births > heard_before
                            and gw.pipeline.latest() is not None, "born")
                sender.publish(spb.node_topic(GROUP, "NCMD", "gw1"), write_true(spb.REBIRTH), qos=1)
                await until(lambda: gw.mqtt.counters.births == 2, "the rebirth asked by NCMD")
                sender.publish(dcmd, write_true("Commands/TARE"), qos=1)
                await until(lambda: gw.mqtt.counters.commands_done + gw.mqtt.counters.commands_refused == 1,
                            "the command handled")
                return gw.mqtt.counters, gw.pipeline.reference_offset_m

        refused, _ = run(scenario(False))
        assert refused.commands_refused == 1 and refused.commands_done == 0
        done, _ = run(scenario(True))
        assert done.commands_done == 1 and done.commands_refused == 0
        sender.loop_stop()
        sender.disconnect()


def test_an_edge_broker_bridged_to_the_plant_broker_carries_everything(tmp_path):
    import paho.mqtt.client as mqtt

    with Broker(tmp_path, name="plant") as plant, \
            Broker(tmp_path, name="edge", bridge_to=plant) as edge, \
            FleetListener("127.0.0.1", plant.port) as host:
        assert host.connected.wait(WAIT_S)
        cfg = mqtt_config(tmp_path, edge.port, commands_enabled=True)

        async def scenario():
            async with running_gateway(cfg) as gw:
                await until(lambda: node_of(host) is not None and node_of(host).online, "NBIRTH via the bridge")
                await until(lambda: device_values(host).get("sample_counter", 0) > 0, "DDATA via the bridge")
                # and back: a command from the plant's side reaches the gateway
                sender = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
                sender.connect("127.0.0.1", plant.port)
                sender.loop_start()
                try:
                    sender.publish(spb.device_topic(GROUP, "DCMD", "gw1", "axis"), write_true("Commands/TARE"),
                                   qos=1)
                    await until(lambda: gw.mqtt.counters.commands_done == 1, "the DCMD through the bridge")
                finally:
                    sender.loop_stop()
                    sender.disconnect()
            await until(lambda: not node_of(host).online, "NDEATH via the bridge")

        run(scenario())


@pytest.mark.parametrize("case", ["wrong credentials", "no broker"])
def test_a_broker_that_refuses_or_is_missing_costs_one_log_line_and_modbus_and_can_keep_serving(
        tmp_path, caplog, case):
    caplog.set_level(logging.INFO, logger="adxlgw")
    users = {"plant": "right"}
    broker = Broker(tmp_path, users=users)
    credentials = tmp_path / "credentials"
    credentials.write_text("plant:wrong\n")
    if case == "wrong credentials":
        broker.start()
        port = broker.port
    else:
        port = free_port()  # nothing listens there
    cfg = gateway_config(tmp_path, "emulated",
                         mqtt={"enabled": True, "port": port, "group_id": GROUP, "edge_node_id": "gw1",
                               "credentials_file": str(credentials)})
    try:
        async def scenario():
            async with running_gateway(cfg) as gw:
                client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
                await client.connect()
                # paho retries after 1 s, then 2 s: a few attempts, still one line
                await until(lambda: sum(r.levelno == logging.ERROR for r in caplog.records) >= 1, "the log line")
                start = time.monotonic()
                while time.monotonic() - start < 4:
                    regs = await read_inputs(client)  # Modbus serves (an error would raise)
                    await asyncio.sleep(0.2)
                assert StatusExtBits.MQTT_DOWN in StatusExtBits(regs["STATUS_EXT"])
                await until(lambda: gw.can.counters.frames_sent > 5, "CAN frames")
                client.close()
                return gw.mqtt.connected

        assert run(scenario()) is False
    finally:
        broker.stop()
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1, errors
    assert f"127.0.0.1:{port}" in errors[0]
    assert ("refused" in errors[0]) if case == "wrong credentials" else ("cannot reach" in errors[0])


def test_a_reload_of_mqtt_is_a_new_session_and_one_that_cannot_start_is_refused_whole(tmp_path):
    """All or nothing across the wires: a reload whose MQTT cannot start (its TLS CA file
    is missing) keeps the Modbus change from happening too, and the old session."""
    with Broker(tmp_path) as broker, FleetListener("127.0.0.1", broker.port) as host:
        assert host.connected.wait(WAIT_S)
        cfg = mqtt_config(tmp_path, broker.port)

        class Reloadable:
            def __init__(self):
                self.cfg = cfg

            def __call__(self):
                return self.cfg

        source = Reloadable()

        async def scenario():
            async with running_gateway(cfg, reload=source) as gw:
                await until(lambda: node_of(host) is not None and node_of(host).online, "the first birth")
                first_bd = node_of(host).bd_seq
                source.cfg = cfg.replace({"mqtt.rate_hz": 10.0})
                await gw.reload()
                assert gw.counters.config_reloads == 1
                await until(lambda: node_of(host).bd_seq == (first_bd + 1) % 256 and node_of(host).online,
                            "the new session's birth, with the next bdSeq")
                node = gw.mqtt
                source.cfg = cfg.replace({"mqtt.rate_hz": 10.0, "mqtt.tls_ca_file": str(tmp_path / "missing.pem"),
                                          "can.period_ms": 20})
                await gw.reload()
                assert gw.counters.config_reload_errors == 1
                assert gw.cfg.mqtt.rate_hz == 10.0 and gw.can.config.period_ms == 10  # nothing of it taken
                await until(lambda: gw.mqtt is not None and gw.mqtt.connected, "MQTT back with the old settings")
                assert gw.mqtt is not node or node.connected

        run(scenario())
