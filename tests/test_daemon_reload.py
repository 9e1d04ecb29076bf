"""Reloads are all or nothing, touch only what changed, and are heard while the board
port is still being opened (issue 16). In-process gateways on real ptys and sockets."""
from __future__ import annotations

import asyncio
import os
import socket

from pymodbus.client import AsyncModbusTcpClient

from drivers.pty_port import PtyPort
from tests.daemon_helpers import gateway_config, read_inputs, running_gateway, wait_for


def run(coro):
    return asyncio.run(coro)


class Reloadable:
    """What a SIGHUP would read: the config the test puts here."""

    def __init__(self, cfg):
        self.cfg = cfg

    def __call__(self):
        return self.cfg


def test_a_reload_that_cannot_bind_is_refused_and_the_old_modbus_keeps_serving(tmp_path):
    pty = PtyPort(tmp_path / "board")
    cfg = gateway_config(tmp_path, str(pty.link), can={"enabled": False})
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            port = gw.modbus.tcp_port
            client = AsyncModbusTcpClient("127.0.0.1", port=port)
            await client.connect()
            await read_inputs(client)
            source.cfg = cfg.replace({"modbus.port": taken.getsockname()[1]})
            await gw.reload()
            assert gw.counters.config_reload_errors == 1 and gw.counters.config_reloads == 0
            assert gw.cfg is cfg and gw.modbus.tcp_port == port
            await read_inputs(client)  # the same connection, still served (an error would raise)
            client.close()

    try:
        run(scenario())
    finally:
        taken.close()
        pty.close(remove_link=True)


def test_a_reload_of_can_alone_keeps_modbus_clients_connected(tmp_path):
    pty = PtyPort(tmp_path / "board")
    cfg = gateway_config(tmp_path, str(pty.link))
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            server = gw.modbus
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            await read_inputs(client)
            source.cfg = cfg.replace({"can.period_ms": 20})
            await gw.reload()
            assert gw.counters.config_reloads == 1 and gw.modbus is server
            assert gw.can.config.period_ms == 20
            await read_inputs(client)  # the same connection
            assert client.connected
            client.close()

    try:
        run(scenario())
    finally:
        pty.close(remove_link=True)


def test_fixing_the_board_port_by_reload_while_it_is_missing_opens_the_new_one(tmp_path):
    pty = PtyPort(tmp_path / "board")
    cfg = gateway_config(tmp_path, str(tmp_path / "no-such-board"), can={"enabled": False})
    source = Reloadable(cfg)

    async def scenario():
        from gateway.daemon import Gateway

        async with Gateway(cfg, reload=source) as gw:
            await asyncio.sleep(0.3)
            assert not gw.ready  # retrying the missing path
            source.cfg = cfg.replace({"serial.port": str(pty.link)})
            await gw.reload()
            await gw.wait_ready(10)
            await wait_for(lambda: gw.source.is_open, 5, what="the new port open")
            assert gw.source.settings.port == str(pty.link)

    try:
        run(scenario())
    finally:
        pty.close(remove_link=True)


def test_a_tare_is_declined_while_the_board_data_is_stale(tmp_path):
    """Issue 13: a tare while STALE would reference a position of a moment ago."""
    from drivers.board_protocol import encode_hello, encode_sample
    from drivers.published_values import Command, StatusBits

    pty = PtyPort(tmp_path / "board")
    # stale after 1.5 s: room for a loaded machine between the samples and the first tare
    cfg = gateway_config(tmp_path, str(pty.link), can={"enabled": False},
                         serial={"stale_after_ms": 1500, "lost_after_ms": 10000})

    async def scenario():
        async with running_gateway(cfg) as gw:
            data = encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)
            data += b"".join(encode_sample(seq, 921, 921, 1843) for seq in range(200))
            os.write(pty.master_fd, data)  # the board talks, then falls silent
            await wait_for(lambda: gw.pipeline.counters.samples == 200, 5, what="the samples")
            assert StatusBits.STALE not in gw.fresh_values().status
            assert gw.on_command(Command.TARE, "test")  # fresh data: taken
            await wait_for(lambda: StatusBits.STALE in gw.fresh_values().status, 5, what="STALE")
            assert not gw.on_command(Command.TARE, "test")

    try:
        run(scenario())
    finally:
        pty.close(remove_link=True)
