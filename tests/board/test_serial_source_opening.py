"""SerialSource: opening errors, settings, and pyserial URLs (loop://, socket://)."""

from __future__ import annotations

import asyncio
import itertools
from pathlib import Path

import pytest
import serial

from drivers.board_decoder import StreamDecoder
from drivers.errors import DriverError, SerialPortError
from drivers.serial_port import SerialSettings, reconnect_delays_s
from drivers.serial_source import SerialSource
from tests.serial_helpers import (
    FAST_BACKOFF,
    READERS,
    Consumer,
    RecordingOpener,
    frames,
    wait_until,
    wire,
)

# --- opening errors -------------------------------------------------------------------


def test_missing_port_fails_at_first_open_with_a_clear_message(tmp_path: Path):
    missing = str(tmp_path / "ttyUSB9")
    source = SerialSource(SerialSettings(port=missing))
    with pytest.raises(SerialPortError) as info:
        source.open()
    message = str(info.value)
    assert missing in message and "No such file or directory" in message and "ENOENT" in message
    assert info.value.port == missing
    assert isinstance(info.value, DriverError)
    assert isinstance(info.value.__cause__, serial.SerialException)
    assert source.state.last_error == message


def test_missing_port_fails_chunks_at_start(tmp_path: Path):
    async def scenario():
        async for _ in SerialSource(SerialSettings(port=str(tmp_path / "none"))).chunks():
            pass

    with pytest.raises(SerialPortError, match="cannot open serial port"):
        asyncio.run(scenario())


def test_a_file_that_is_not_a_tty_is_refused(tmp_path: Path):
    not_a_tty = tmp_path / "plain-file"
    not_a_tty.write_bytes(b"")
    with pytest.raises(SerialPortError, match="cannot open serial port"):
        SerialSource(SerialSettings(port=str(not_a_tty))).open()


def test_second_reader_of_the_same_port_is_refused(make_pty):
    pty = make_pty()
    with (
        SerialSource(SerialSettings(port=pty.path)),
        pytest.raises(SerialPortError, match="another process holds the port"),
    ):
        SerialSource(SerialSettings(port=pty.path)).open()


def test_settings_are_validated():
    with pytest.raises(ValueError):
        SerialSettings(port="")
    with pytest.raises(ValueError):
        SerialSettings(port="loop://", reconnect_initial_s=1.0, reconnect_max_s=0.5)
    for wake in (0, 256):
        with pytest.raises(ValueError, match="wake_min_bytes"):
            SerialSettings(port="loop://", wake_min_bytes=wake)
    with pytest.raises(ValueError, match="unknown serial settings: baud"):
        SerialSource.from_config({"port": "loop://", "baud": 9600})
    assert SerialSource.from_config({"port": "loop://", "baudrate": 9600}).settings.baudrate == 9600


def test_backoff_schedule_doubles_up_to_the_cap():
    settings = SerialSettings(port="x", reconnect_initial_s=0.1, reconnect_max_s=5.0, reconnect_multiplier=2.0)
    delays = list(itertools.islice(reconnect_delays_s(settings), 9))
    assert delays == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.6, 3.2, 5.0, 5.0, 5.0])


# --- pyserial URLs --------------------------------------------------------------------




@READERS
def test_loop_url_read_available_and_thread_backed_reading(mode):
    opener = RecordingOpener()
    sent = frames(range(50))

    source = SerialSource(SerialSettings(port="loop://"), opener=opener)
    source.open()
    opener.ports[0].write(wire(sent[:5]))
    assert StreamDecoder().feed(source.read_available()) == sent[:5]

    async def scenario():
        consumer = Consumer(source, mode)
        await asyncio.sleep(0)
        opener.ports[0].write(wire(sent[5:]))
        await wait_until(lambda: len(consumer.frames) == 45, "loop:// frames")
        await consumer.stop()
        return consumer.frames

    assert asyncio.run(scenario()) == sent[5:]


@READERS
def test_socket_url_reconnects_after_the_peer_hangs_up(mode):
    """socket:// has a descriptor, so chunks() waits on the event loop's reader;
    a peer hang-up is pyserial's 'socket disconnected', i.e. a loss."""
    sent = frames(range(30))

    async def scenario():
        connections: list[asyncio.StreamWriter] = []
        # pyserial drops whatever is buffered while it opens, so the "board" sends
        # only once the source reports the port open.
        may_send = [asyncio.Event(), asyncio.Event()]

        async def board(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            connections.append(writer)
            n = len(connections) - 1
            await may_send[n].wait()
            writer.write(wire(sent[:10] if n == 0 else sent[10:]))
            await writer.drain()
            if n == 0:
                writer.close()  # the link drops

        server = await asyncio.start_server(board, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        source = SerialSource(SerialSettings(port=f"socket://127.0.0.1:{port}", **FAST_BACKOFF))
        consumer = Consumer(source, mode)
        await wait_until(lambda: source.state.is_open, "connected")
        may_send[0].set()
        await wait_until(lambda: source.state.reconnects == 1, "reconnected")
        may_send[1].set()
        await wait_until(lambda: len(consumer.frames) == 30, "frames over two connections")
        state = source.state
        await consumer.stop()
        for writer in connections:
            writer.close()
        server.close()
        await server.wait_closed()
        return consumer.frames, state

    got, state = asyncio.run(scenario())
    assert got == sent
    assert (state.losses, state.reconnects, state.is_open) == (1, 1, True)
    assert "socket disconnected" in state.last_error
