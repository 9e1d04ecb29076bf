"""The gateway daemon in-process against the emulated board on a real pty, a pymodbus
client on TCP, and a python-can virtual bus decoded with cantools."""
import asyncio
import socket
import subprocess
import time
import uuid

import can
import cantools
import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers.can_frames_text import dbc_text
from drivers.modbus_map import MAP_VERSION, CommandResult
from drivers.published_values import StatusBits
from gateway.daemon.sample_loop import OUTAGE_S
from tests.daemon_helpers import CLI, Emulator, gateway_config, read_inputs, running_gateway, wait_for

# the emulated board's sample period: T2 = RSET / 125 MΩ with its 250 kΩ (adxlgw emulate's default)
BOARD_PERIOD_S = 250e3 / 125e6

pytestmark = pytest.mark.slow


def run(coro):
    return asyncio.run(coro)


@pytest.fixture
def board(tmp_path):
    emu = Emulator(tmp_path, "--strokes", "4", "--seed", "21")
    yield emu
    emu.stop()


def test_board_to_modbus_and_can(tmp_path, board):
    cfg = gateway_config(tmp_path, str(board.link))
    db = cantools.database.load_string(dbc_text(), "dbc")

    async def scenario():
        async with running_gateway(cfg) as gw:
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            await wait_for(lambda: gw.pipeline.counters.samples > 1000, 20, what="1000 samples")
            # the estimator holds its outputs until the bias is measured at the first standstill
            await wait_for(lambda: StatusBits.VALID in gw.fresh_values().status, 30, what="VALID")
            regs = await read_inputs(client)
            status = StatusBits(regs["STATUS"])
            assert StatusBits.VALID in status and StatusBits.NOT_REFERENCED in status
            assert not status & (StatusBits.STALE | StatusBits.BOARD_LOST)
            assert regs["SAMPLE_COUNTER"] > 1000 and regs["LAST_SAMPLE_AGE"] < 100
            assert regs["BOARD_TEMPERATURE"] == 2500  # 0.01 °C units
            assert regs["MAP_VERSION"] == MAP_VERSION and regs["CRC_ERRORS"] == 0
            # the emulated robot strokes between 0 and 0.3 m
            assert -0.02 < regs["POSITION"] < 0.32
            assert regs["POSITION_UM"] == pytest.approx(regs["POSITION"] * 1e6, abs=2)
            beat = regs["HEARTBEAT"]
            await asyncio.sleep(0.1)
            assert (await read_inputs(client))["HEARTBEAT"] != beat

            # CAN: the cyclic frames decode with the shipped DBC and carry the same state
            bus = can.Bus(interface="virtual", channel=cfg.can.channel)
            try:
                seen = {}
                for _ in range(50):
                    msg = await asyncio.to_thread(bus.recv, 1.0)
                    assert msg is not None
                    seen[msg.arbitration_id] = db.decode_message(msg.arbitration_id, msg.data)
                    if len(seen) >= 2:
                        break
                pos_msg = db.get_message_by_name("ADXL_Position")
                decoded = seen[pos_msg.frame_id]
                assert any("Position" in k for k in decoded)
            finally:
                bus.shutdown()

            # tare over Modbus: position := 0 here, reference gained
            await wait_for(lambda: StatusBits.STANDSTILL in gw.fresh_values().status, 20, what="a standstill")
            wr = await client.write_register(0, 1)
            assert not wr.isError()
            regs = await read_inputs(client)
            assert regs["LAST_COMMAND_RESULT"] == 1
            assert abs(regs["POSITION"]) < 0.002
            assert StatusBits.NOT_REFERENCED not in StatusBits(regs["STATUS"])
            client.close()
        state = (tmp_path / "state.json").read_text()
        assert "tare_offset_m" in state

    run(scenario())


def test_keeps_serving_through_faults_and_says_what_happened(tmp_path):
    emu = Emulator(tmp_path, "--strokes", "2", "--garbage-every", "0.3", "--burst-every", "0.7",
                   "--drop-every", "0.4", "--reset-every", "2.5", "--reopen-every", "3")
    cfg = gateway_config(tmp_path, str(emu.link))

    async def scenario():
        async with running_gateway(cfg) as gw:
            port = gw.modbus.tcp_port
            client = AsyncModbusTcpClient("127.0.0.1", port=port)
            await client.connect()
            await wait_for(lambda: gw.board.source.state.reconnects >= 1 and gw.pipeline.counters.samples > 2000, 30,
                           what="a reconnect after the pty vanished")
            # clients that connect and drop, and malformed requests, between good reads
            for junk in (b"\x00\x01\x00\x00\x00\x06\x01\x04\x00", b"\xff" * 40,
                         b"\x00\x01\x00\x00\x00\x06\x01\x63\x00\x00\x00\x01"):
                with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
                    s.sendall(junk)
            regs = await read_inputs(client)
            assert regs["LOST_SAMPLES"] > 0
            assert regs["BOARD_RESETS"] >= 1
            await wait_for(lambda: gw.pipeline.decoder_counters.bytes_skipped > 0, 10, what="garbage skipped")
            # SAMPLES_LOST is held 10 s after a loss; on a loaded host the emulated board's
            # reopen can keep the line silent about that long (a CI run read the status in
            # such a gap), so the status is read until it shows a loss, as losses recur every 0.4 s
            deadline = time.monotonic() + 15
            while StatusBits.SAMPLES_LOST not in StatusBits(regs["STATUS"]):
                assert time.monotonic() < deadline, f"SAMPLES_LOST never shown: {StatusBits(regs['STATUS'])!r}"
                await asyncio.sleep(0.1)
                regs = await read_inputs(client)
            # a board that resets every 2.5 s may reset mid-move: its position is not
            # trusted (and not VALID) until a stop is seen on evidence — never confidently wrong
            await wait_for(lambda: StatusBits.POSITION_UNTRUSTED in gw.fresh_values().status, 10,
                           what="POSITION_UNTRUSTED after a board reset")
            assert StatusBits.VALID not in gw.fresh_values().status
            await wait_for(lambda: gw.pipeline.counters.samples > regs["SAMPLE_COUNTER"] + 500, 10,
                           what="samples still flowing")
            client.close()

    try:
        run(scenario())
    finally:
        emu.stop()


def test_board_lost_is_flagged_and_recovered(tmp_path, board):
    cfg = gateway_config(tmp_path, str(board.link))

    async def scenario():
        async with running_gateway(cfg) as gw:
            await wait_for(lambda: StatusBits.VALID in gw.fresh_values().status, 20, what="VALID")
            lost_before = gw.fresh_values().lost_samples
            board.proc.send_signal(19)  # SIGSTOP: the board falls silent, the port stays
            try:
                await wait_for(lambda: StatusBits.STALE in gw.fresh_values().status, 5, what="STALE")
                await wait_for(lambda: StatusBits.BOARD_LOST in gw.fresh_values().status, 5, what="BOARD_LOST")
                assert StatusBits.VALID not in gw.fresh_values().status
            finally:
                board.proc.send_signal(18)  # SIGCONT
            await wait_for(lambda: not gw.fresh_values().status & (StatusBits.STALE | StatusBits.BOARD_LOST), 10,
                           what="the board's data again")
            # The board's seq says what the silence cost. The emulated board, continued, writes
            # the samples it owes (a backlog, nothing lost: the estimate goes on); the port may
            # also have been reopened meanwhile, losing what was in flight. Samples lost over
            # more than OUTAGE_S of the board's clock: the axis may have moved unseen, so the
            # position is not trusted (nor VALID) until a stop is seen on evidence.
            values = gw.fresh_values()
            lost_s = (values.lost_samples - lost_before) * BOARD_PERIOD_S
            started_over = gw.intake.events.outage_at_s is not None
            assert started_over == (lost_s > OUTAGE_S), (lost_s, started_over)
            if started_over:
                assert StatusBits.POSITION_UNTRUSTED in values.status and StatusBits.VALID not in values.status

    run(scenario())


def test_can_send_failures_are_counted_and_publishing_goes_on(tmp_path, board):
    cfg = gateway_config(tmp_path, str(board.link))

    class FlakyBus(can.interfaces.virtual.VirtualBus):
        """A virtual bus whose sends fail once told to (as a full SocketCAN queue does)."""

        broken = False

        def send(self, msg, timeout=None):
            if FlakyBus.broken:
                raise can.CanOperationError("No buffer space available [Error Code 105]")
            super().send(msg, timeout)

    def flaky_bus(**kwargs):
        kwargs.pop("interface", None)
        return FlakyBus(**kwargs)

    async def scenario():
        async with running_gateway(cfg, can_bus_factory=flaky_bus) as gw:
            await wait_for(lambda: gw.can is not None and gw.can.counters.frames_sent > 5, 20, what="CAN frames")
            FlakyBus.broken = True
            await wait_for(lambda: gw.fresh_values().can_send_errors > 10, 5, what="send errors counted")
            samples = gw.pipeline.counters.samples
            await asyncio.sleep(0.3)
            assert gw.pipeline.counters.samples > samples  # the board side is unaffected
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            assert (await read_inputs(client))["CAN_SEND_ERRORS"] > 10
            client.close()

    run(scenario())


def on_a_quiet_pty(tmp_path, body, can=None) -> None:
    """Run `await body(gw, client, pty)`: a gateway (CAN off unless `can` says) on a pty
    that nobody plays unless the test writes to it, and a Modbus client connected to it.
    Its quiet tick is an hour: nothing but what a test checks may take the bytes."""
    from drivers.pty_port import PtyPort

    pty = PtyPort(tmp_path / "board")
    cfg = gateway_config(tmp_path, str(pty.link), can=can or {"enabled": False})

    async def scenario():
        async with running_gateway(cfg, publish_tick_s=3600.0) as gw:
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            try:
                await body(gw, client, pty)
            finally:
                client.close()

    try:
        run(scenario())
    finally:
        pty.close(remove_link=True)


def test_a_modbus_read_shows_samples_that_wait_in_a_batch(tmp_path):
    """Where the port cannot batch, received bytes wait (Gateway.receive) until
    something needs the numbers; a Modbus read is such a need: it must show every
    sample received before it."""
    from drivers.board_protocol import encode_hello, encode_sample

    async def body(gw, client, pty):
        before = (await read_inputs(client))["SAMPLE_COUNTER"]
        gw.receive(encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0))
        for seq in range(3):
            gw.receive(encode_sample(seq, 900, 900, 1843))
        assert gw.intake.waiting_chunks, "the bytes were handled at once: nothing to check"
        assert gw.pipeline.counters.samples == before
        regs = await read_inputs(client)
        assert regs["SAMPLE_COUNTER"] == before + 3
        assert not gw.intake.waiting_chunks

    on_a_quiet_pty(tmp_path, body)


def board_bytes_below_one_batch() -> bytes:
    from drivers.board_protocol import SAMPLE_FRAME_LENGTH, encode_hello, encode_sample

    data = encode_hello(uptime_s=0, tick_hz=921_600, temp_centi_c=2500, fw_major=1, fw_minor=0)
    data += b"".join(encode_sample(seq, 900, 900, 1843) for seq in range(3))  # 3 samples
    assert len(data) < 5 * SAMPLE_FRAME_LENGTH  # less than one batch: no wakeup
    return data


def bytes_waiting(gw) -> int:
    """Bytes in the gateway's tty that nobody has read yet."""
    return gw.board.source.bytes_waiting()


def test_a_modbus_read_takes_the_samples_still_waiting_in_the_port(tmp_path):
    """The kernel wakes the gateway only once serial.batch_frames (default 5) frames'
    bytes wait (termios VMIN). A Modbus read must not show older numbers than a wakeup
    per frame would: it takes the bytes waiting in the port first."""
    import os

    from drivers.board_protocol import SAMPLE_FRAME_LENGTH

    data = board_bytes_below_one_batch()
    waiting = bytes_waiting

    async def body(gw, client, pty):
        assert gw.board.source.wake_min_bytes == 5 * SAMPLE_FRAME_LENGTH
        before = (await read_inputs(client))["SAMPLE_COUNTER"]
        os.write(pty.master_fd, data)
        await wait_for(lambda: waiting(gw) == len(data), what="the bytes in the gateway's tty")
        await asyncio.sleep(0.05)
        assert gw.pipeline.counters.samples == before and waiting(gw) == len(data), "woken below a batch"
        regs = await read_inputs(client)
        assert regs["SAMPLE_COUNTER"] == before + 3
        assert waiting(gw) == 0

    on_a_quiet_pty(tmp_path, body)


def test_a_can_cycle_takes_the_samples_still_waiting_in_the_port(tmp_path):
    """Strictly cyclic CAN (sync_to_updates = false): the frames go out on the
    publisher's timer, not with a batch; each must carry what has arrived by then."""
    import os

    data = board_bytes_below_one_batch()

    async def body(gw, client, pty):
        sent = gw.can.counters.frames_sent
        before = gw.pipeline.counters.samples
        os.write(pty.master_fd, data)
        await wait_for(lambda: gw.pipeline.counters.samples == before + 3, what="a CAN cycle taking the bytes")
        assert bytes_waiting(gw) == 0
        assert gw.can.counters.frames_sent > sent

    on_a_quiet_pty(tmp_path, body, can={"sync_to_updates": False})


def test_two_gateways_on_one_can_bus_each_on_its_identifiers(tmp_path):
    """Two daemons, one virtual CAN channel, can.base_id 0x120 and 0x200: each one's frames
    decode with the DBC `adxlgw dbc --config` writes for it, no identifier clashes."""
    from drivers.pty_port import PtyPort

    channel = f"two-{uuid.uuid4().hex[:8]}"
    ptys = [PtyPort(tmp_path / f"board{k}") for k in range(2)]
    cfgs = [gateway_config(tmp_path / f"gw{k}", str(ptys[k].link), can={"channel": channel, "base_id": base})
            for k, base in enumerate((0x120, 0x200))]
    dbcs = []
    for k, cfg in enumerate(cfgs):
        path = tmp_path / f"gw{k}.toml"
        path.write_text(f'[can]\ninterface = "virtual"\nchannel = "{channel}"\nbase_id = {cfg.can.base_id}\n'
                        f'[state]\npath = "{tmp_path}/s{k}.json"\n[serial]\nport = "/dev/null"\n')
        out = subprocess.run([*CLI, "dbc", "--config", str(path)], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        dbcs.append(cantools.database.load_string(out.stdout, database_format="dbc"))

    async def scenario():
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            async with running_gateway(cfgs[0]), running_gateway(cfgs[1]):
                ids = set()
                for _ in range(200):
                    msg = await asyncio.to_thread(bus.recv, 1.0)
                    assert msg is not None
                    ids.add(msg.arbitration_id)
                    if {0x120, 0x121, 0x200, 0x201} <= ids:
                        break
                assert {0x120, 0x121, 0x200, 0x201} <= ids, ids
                for db, base in zip(dbcs, (0x120, 0x200), strict=False):
                    assert db.get_message_by_name("ADXL_Position").frame_id == base
                    assert db.get_message_by_name("ADXL_Command").frame_id == base + 0x10
        finally:
            bus.shutdown()

    try:
        run(scenario())
    finally:
        for pty in ptys:
            pty.close(remove_link=True)


def test_start_at_rest_is_believed_only_after_an_orderly_stop_at_rest(tmp_path, caplog):
    """`estimator.start_at_rest` promises the axis stands at start. A first start (no state
    file) and a start after an orderly stop at a trusted standstill keep that promise; a
    start after a crash, kill -9 or watchdog abort may come mid-move (the fault benchmark's
    restart took a cruise for a rest, 0.8 m off with VALID set), so there it is not believed."""
    import json

    from gateway.daemon.supervisor import Gateway

    emu = Emulator(tmp_path, "--scenario", "standstill")
    cfg = gateway_config(tmp_path, str(emu.link))
    state = tmp_path / "state.json"
    try:
        assert Gateway(cfg).starts_at_rest  # a first start: nothing says otherwise

        async def scenario():
            async with running_gateway(cfg) as gw:
                # on disk while it runs: no orderly-stop mark (a kill -9 now leaves it so)
                assert json.loads(state.read_text())["stopped_at_rest_unix_s"] is None

                def trusted_rest():
                    status = gw.fresh_values().status
                    return StatusBits.STANDSTILL in status and StatusBits.VALID in status \
                        and StatusBits.POSITION_UNTRUSTED not in status
                await wait_for(trusted_rest, 30, what="a trusted standstill")
        run(scenario())
    finally:
        emu.stop()
    saved = json.loads(state.read_text())
    assert saved["stopped_at_rest_unix_s"] is not None
    assert Gateway(cfg).starts_at_rest

    # what a save while running leaves behind when the process is killed
    saved["stopped_at_rest_unix_s"] = None
    state.write_text(json.dumps(saved))
    caplog.clear()
    assert not Gateway(cfg).starts_at_rest
    assert "start_at_rest not believed" in caplog.text
    # a state file from before the field existed says nothing of an orderly stop either
    del saved["stopped_at_rest_unix_s"]
    state.write_text(json.dumps(saved))
    assert not Gateway(cfg).starts_at_rest
    # the setting off: never believed, whatever the file says
    assert not Gateway(gateway_config(tmp_path, str(emu.link), estimator={"start_at_rest": False})).starts_at_rest


def test_modbus_answers_while_the_board_side_is_built_and_says_nothing_is_measured(tmp_path, monkeypatch):
    """The wires listen before numpy, numba and the compiled estimator are loaded (a second or
    more): a PLC polling a gateway that (re)starts gets answers at once, and those answers say
    that nothing is measured yet — no VALID, BOARD_LOST, NOT_REFERENCED, NaN position — and
    commands are declined; once built, the gateway opens the board's port and serves as ever."""
    import math
    import threading

    from gateway.daemon import sample_pipeline
    from gateway.daemon.supervisor import Gateway

    release = threading.Event()
    real = sample_pipeline.SamplePipeline

    class HeldPipeline(real):  # the build waits for the test: what a slow load looks like
        def __init__(self, *args, **kwargs):
            assert release.wait(30), "never released"
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(sample_pipeline, "SamplePipeline", HeldPipeline)
    emu = Emulator(tmp_path, "--scenario", "standstill")
    cfg = gateway_config(tmp_path, str(emu.link), estimator={"start_at_rest": False})

    async def scenario():
        gw = Gateway(cfg)
        starting = asyncio.create_task(gw.start())
        try:
            await wait_for(lambda: gw.modbus is not None and gw.modbus.tcp_port, 20, what="Modbus listening")
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            regs = await read_inputs(client)
            status = StatusBits(regs["STATUS"])
            assert StatusBits.VALID not in status
            assert status & StatusBits.BOARD_LOST and status & StatusBits.NOT_REFERENCED
            assert status & StatusBits.POSITION_UNTRUSTED  # start_at_rest off: the axis may move
            assert math.isnan(regs["POSITION"]) and regs["SAMPLE_COUNTER"] == 0
            assert not gw.ready and not starting.done()
            wr = await client.write_register(0, 1)  # CMD_TARE
            assert wr.isError()  # exception 04: declined
            assert (await read_inputs(client))["LAST_COMMAND_RESULT"] == CommandResult.DECLINED
            release.set()
            await starting
            await gw.wait_ready(30)
            await wait_for(lambda: gw.pipeline.counters.samples > 100, 20, what="samples")
            regs = await read_inputs(client)
            assert regs["SAMPLE_COUNTER"] > 100 and not StatusBits(regs["STATUS"]) & StatusBits.BOARD_LOST
            client.close()
        finally:
            release.set()
            await asyncio.gather(starting, return_exceptions=True)
            await gw.stop()

    try:
        run(scenario())
    finally:
        emu.stop()


def test_a_stop_while_the_estimator_loads_does_not_wait_for_it(tmp_path, monkeypatch):
    """SIGTERM (request_stop) while the board side is still being built — seconds warm,
    minutes when numba compiles into an empty cache — ends `run` at once: the unit's
    TimeoutStopSec is 2 s. The wires are closed and the state file is as it was."""
    import json
    import threading

    from gateway.daemon import sample_pipeline
    from gateway.daemon.supervisor import Gateway

    release = threading.Event()
    real = sample_pipeline.SamplePipeline

    class HeldPipeline(real):
        def __init__(self, *args, **kwargs):
            assert release.wait(60), "never released"
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(sample_pipeline, "SamplePipeline", HeldPipeline)
    cfg = gateway_config(tmp_path, str(tmp_path / "no-board-yet"))

    async def scenario():
        gw = Gateway(cfg)
        running = asyncio.create_task(gw.run())
        await wait_for(lambda: gw.modbus is not None and gw.modbus.tcp_port, 20, what="Modbus listening")
        port = gw.modbus.tcp_port
        gw.request_stop()
        assert await asyncio.wait_for(running, 10) == 0  # not waiting for the build
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=1).close()

    try:
        run(scenario())  # asyncio.run's end included: it does not wait for the build's thread either
        builders = [t for t in threading.enumerate() if t.name.startswith("board-side")]
        assert builders and all(t.is_alive() for t in builders) and not release.is_set()
    finally:
        release.set()
    for t in builders:
        t.join(60)
    assert json.loads((tmp_path / "state.json").read_text())["stopped_at_rest_unix_s"] is None
