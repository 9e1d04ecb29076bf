"""The daemon's reloads and commands on real ptys and sockets: reloads are all or
nothing, touch only what changed and are heard while the board port is still being
opened (issue 16); a tare is declined while STALE and the machine's standstill hint
comes in over Modbus and CAN (issue 13)."""
from __future__ import annotations

import asyncio
import os
import socket

import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers.pty_port import PtyPort
from tests.daemon_helpers import gateway_config, read_inputs, running_gateway, wait_for


def run(coro):
    return asyncio.run(coro)


@pytest.fixture
def pty(tmp_path):
    """A board's pty that nobody plays unless the test writes to it."""
    port = PtyPort(tmp_path / "board")
    yield port
    port.close(remove_link=True)


class Reloadable:
    """What a SIGHUP would read: the config the test puts here."""

    def __init__(self, cfg):
        self.cfg = cfg

    def __call__(self):
        return self.cfg


def test_a_reload_that_cannot_bind_is_refused_and_the_old_modbus_keeps_serving(tmp_path, pty):
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


def test_a_reload_to_a_missing_serial_port_is_refused_and_the_board_kept(tmp_path, pty):
    """All or nothing: it used to be applied (the board dropped, BOARD_LOST) while every
    other bad reload was refused."""
    cfg = gateway_config(tmp_path, str(pty.link), can={"enabled": False})
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            opened = gw.board.source
            source.cfg = cfg.replace({"serial.port": str(tmp_path / "no-such-board")})
            await gw.reload()
            assert gw.counters.config_reload_errors == 1 and gw.counters.config_reloads == 0
            assert gw.cfg is cfg and gw.board.source is opened and opened.is_open

    run(scenario())


def test_a_reload_of_can_alone_keeps_modbus_clients_connected(tmp_path, pty):
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

    run(scenario())


def test_fixing_the_board_port_by_reload_while_it_is_missing_opens_the_new_one(tmp_path, pty):
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
            await wait_for(lambda: gw.board.source.is_open, 5, what="the new port open")
            assert gw.board.source.settings.port == str(pty.link)

    run(scenario())


def test_a_tare_is_declined_while_the_board_data_is_stale(tmp_path, pty):
    """Issue 13: a tare while STALE would reference a position of a moment ago."""
    from drivers.board_protocol import encode_hello, encode_sample
    from drivers.published_values import Command, StatusBits

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

    run(scenario())


def test_the_machines_standstill_hint_over_modbus_and_can(tmp_path, pty):
    """Issue 13: the PLC's "axis at rest" over Modbus settles a restart the accelerometer
    cannot decide alone; it is shown in STATUS_EXT, expires after hint_timeout_ms, and the
    same hint arrives as a CAN command."""
    import can

    from drivers.board_protocol import encode_hello, encode_sample
    from drivers.can_frames import ACK_FRAME, AckResult, encode_command, unpack
    from drivers.modbus_map import BY_NAME
    from drivers.published_values import Command, StatusBits, StatusExtBits

    cfg = gateway_config(tmp_path, str(pty.link), can={"commands_enabled": True},
                         serial={"stale_after_ms": 1500, "lost_after_ms": 10000},
                         estimator={"start_at_rest": False, "hint_timeout_ms": 1500},
                         modbus={"write_allow": ["127.0.0.1"]})

    def play(seq0: int, n: int) -> int:
        os.write(pty.master_fd, b"".join(encode_sample((seq0 + k) & 0xFFFF, 921, 921, 1843) for k in range(n)))
        return seq0 + n

    async def scenario():
        async with running_gateway(cfg) as gw:
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            os.write(pty.master_fd, encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1,
                                                 fw_minor=0))
            seq = play(0, 300)  # 0.6 s at rest: may be a cruise for a gateway that may start mid-move
            await wait_for(lambda: gw.pipeline.counters.samples >= 300, 5, what="the samples")
            regs = await read_inputs(client)
            assert StatusBits.POSITION_UNTRUSTED in StatusBits(regs["STATUS"])
            assert StatusBits.VALID not in StatusBits(regs["STATUS"])
            # the PLC: "in position"
            assert not (await client.write_register(BY_NAME["CMD_HINT_AT_REST"].address, 1)).isError()
            seq = play(seq, 200)
            await wait_for(lambda: gw.pipeline.counters.samples >= 500, 5, what="the samples")
            regs = await read_inputs(client)
            ext = StatusExtBits(regs["STATUS_EXT"])
            assert StatusExtBits.HINT_AT_REST in ext and StatusExtBits.STOP_BY_HINT in ext
            assert StatusBits.POSITION_UNTRUSTED not in StatusBits(regs["STATUS"])
            assert StatusBits.STANDSTILL in StatusBits(regs["STATUS"])
            # not written again: the hint expires
            await wait_for(lambda: StatusExtBits.HINT_AT_REST not in gw.fresh_values().status_ext, 5,
                           what="the hint to expire")
            # over CAN: "moving", acknowledged, shown
            with can.Bus(interface="virtual", channel=cfg.can.channel) as bus:
                bus.send(can.Message(arbitration_id=0x130, data=encode_command(Command.HINT_MOVING, 3),
                                     is_extended_id=False))
                deadline = asyncio.get_running_loop().time() + 5
                while True:
                    msg = await asyncio.to_thread(bus.recv, 0.5)
                    if msg is not None and msg.arbitration_id == ACK_FRAME.frame_id:
                        break
                    assert asyncio.get_running_loop().time() < deadline, "no acknowledge"
                assert unpack(ACK_FRAME, msg.data)["Ack_Result"] == AckResult.DONE
            play(seq, 10)
            await wait_for(lambda: StatusExtBits.HINT_MOVING in gw.fresh_values().status_ext, 5, what="HINT_MOVING")
            client.close()

    run(scenario())


def test_a_reload_shows_at_once_on_modbus_even_while_the_board_is_silent(tmp_path, pty):
    """CONFIG_RELOADED is news on the wires when the reload is applied, not at the board's
    next sample: a reload that changes no wire leaves each wire as it was, and a silent
    board (a slow emulated CPU) publishes nothing new."""
    from drivers.published_values import StatusBits

    cfg = gateway_config(tmp_path, str(pty.link), can={"enabled": False})
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            assert StatusBits.CONFIG_RELOADED not in StatusBits((await read_inputs(client))["STATUS"])
            await gw.reload()  # the same config: no wire changes
            assert gw.counters.config_reloads == 1
            assert StatusBits.CONFIG_RELOADED in StatusBits((await read_inputs(client))["STATUS"])
            client.close()

    run(scenario())


def test_a_reload_of_the_travel_reaches_the_published_sigma_and_the_state_file_check(tmp_path, pty):
    """estimator.travel_m bounds the published σ and the position a later start restores:
    a reload that changes it changes both."""
    from gateway.daemon.state_store import PersistentState

    cfg = gateway_config(tmp_path, str(pty.link))
    source = Reloadable(cfg)

    async def scenario():
        async with running_gateway(cfg, reload=source) as gw:
            assert gw.pipeline.travel_m == (-10.0, 10.0)
            source.cfg = cfg.replace({"estimator.travel_m": [-0.5, 1.5]})
            await gw.reload()
            assert gw.counters.config_reloads == 1 and gw.pipeline.travel_m == (-0.5, 1.5)
        return gw

    store = run(scenario()).state_store
    store.save(PersistentState(last_position_m=2.0, saved_at_unix_s=1.0))  # inside the old travel
    assert store.load().last_position_m is None and "outside the axis's travel" in store.last_error
