"""SerialSource against real parts: pty pairs, pyserial's loop://, a TCP socket://.

Timing is never asserted as a lower bound. Waiting loops have generous deadlines that
only a broken source would hit; "does not spin" is asserted as an upper bound on open
attempts derived from the back-off schedule and the measured elapsed time (a busy loop
would make thousands).
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import struct
import termios
import time
from pathlib import Path

import pytest
import serial

from drivers.board_decoder import StreamDecoder
from drivers.errors import SerialPortError
from drivers.serial_port import SerialSettings
from drivers.serial_source import SerialSource
from tests.serial_helpers import (
    DEADLINE_S,
    FAST_BACKOFF,
    READERS,
    Consumer,
    Pty,
    RecordingOpener,
    frames,
    max_attempts_within,
    wait_until,
    wire,
)

# --- pty ------------------------------------------------------------------------------




@READERS
def test_reads_frames_from_a_pty(make_pty, mode):
    pty = make_pty()
    sent = frames(range(200))

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path))
        consumer = Consumer(source, mode)
        await wait_until(lambda: source.state.is_open, "port open")
        os.write(pty.master, wire(sent))
        await wait_until(lambda: len(consumer.frames) >= len(sent), "frames")
        await consumer.stop()
        return consumer, source.state

    consumer, state = asyncio.run(scenario())
    assert consumer.frames == sent
    assert state.bytes_read == len(wire(sent))
    assert (state.losses, state.reconnects, state.open_attempts) == (0, 0, 1)
    assert consumer.decoder.counters.bytes_skipped == 0


def test_deliver_reads_once_per_arrival_and_keeps_the_reader_registered(make_pty):
    """One read per burst of bytes on the line, and the descriptor is registered with
    the loop once for the whole time the port is open (not once per chunk)."""
    pty = make_pty()
    sent = frames(range(20))

    async def scenario():
        loop = asyncio.get_running_loop()
        registrations = []
        add_reader = loop.add_reader
        loop.add_reader = lambda fd, cb, *args: (registrations.append(fd), add_reader(fd, cb, *args))[1]
        source = SerialSource(SerialSettings(port=pty.path))
        consumer = Consumer(source)
        await wait_until(lambda: source.state.is_open, "port open")
        await asyncio.sleep(0.05)
        for k, sample in enumerate(sent):
            os.write(pty.master, wire([sample]))
            await wait_until(lambda k=k: len(consumer.frames) == k + 1, f"frame {k}")
        state = source.state
        await consumer.stop()
        return consumer.frames, state, registrations

    got, state, registrations = asyncio.run(scenario())
    assert got == sent
    assert state.reads == len(sent)
    assert len(registrations) == 1


def test_close_from_the_loop_body_ends_chunks_and_a_later_read_reopens(make_pty):
    pty = make_pty()

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path))
        source.open()
        os.write(pty.master, wire(frames(range(2))))
        got = b""
        async for chunk in source.chunks():
            got += chunk
            if len(got) >= 30:
                source.close()
        return source, got

    source, got = asyncio.run(scenario())
    assert StreamDecoder().feed(got) == frames(range(2))
    assert not source.state.is_open
    assert source.read_available() == b""
    assert source.state.is_open and source.state.open_attempts == 2
    source.close()


def test_close_from_consume_ends_deliver(make_pty):
    pty = make_pty()

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path))
        source.open()
        got = bytearray()

        def consume(chunk: bytes) -> None:
            got.extend(chunk)
            if len(got) >= 30:
                source.close()

        os.write(pty.master, wire(frames(range(2))))
        await asyncio.wait_for(source.deliver(consume), DEADLINE_S)
        return source, bytes(got)

    source, got = asyncio.run(scenario())
    assert StreamDecoder().feed(got) == frames(range(2))
    assert not source.state.is_open


def test_close_from_another_task_ends_deliver(make_pty):
    pty = make_pty()

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path))
        got = bytearray()
        task = asyncio.create_task(source.deliver(got.extend))
        await wait_until(lambda: source.state.is_open, "port open")
        os.write(pty.master, wire(frames(range(1))))
        await wait_until(lambda: len(got) == 15, "a frame")
        source.close()
        await asyncio.wait_for(task, DEADLINE_S)
        return source.state

    state = asyncio.run(scenario())
    assert not state.is_open and state.losses == 0


def test_an_error_in_consume_ends_deliver_with_it(make_pty):
    pty = make_pty()

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path))
        source.open()

        def consume(chunk: bytes) -> None:
            raise RuntimeError("consumer broke")

        os.write(pty.master, wire(frames(range(1))))
        with pytest.raises(RuntimeError, match="consumer broke"):
            await asyncio.wait_for(source.deliver(consume), DEADLINE_S)
        source.close()

    asyncio.run(scenario())


def test_read_available_never_blocks_and_read_waits_at_most_its_timeout(make_pty):
    pty = make_pty()
    with SerialSource(SerialSettings(port=pty.path)) as source:
        assert source.read_available() == b""
        assert source.read(timeout_s=0.01) == b""
        os.write(pty.master, wire(frames(range(3))))
        got = b""
        deadline = time.monotonic() + DEADLINE_S
        while len(got) < 45 and time.monotonic() < deadline:
            got += source.read(timeout_s=0.05)
        assert StreamDecoder().feed(got) == frames(range(3))
        assert source.read_available(max_bytes=10) == b""


def test_pty_hangup_with_reconnect_disabled_raises_naming_the_port(make_pty):
    pty = make_pty()
    source = SerialSource(SerialSettings(port=pty.path, reconnect=False))
    source.open()
    pty.unplug()
    with pytest.raises(SerialPortError, match="lost") as info:
        source.read(timeout_s=1.0)
    assert info.value.port == pty.path
    assert pty.path in str(info.value)
    assert isinstance(info.value.__cause__, serial.SerialException)
    state = source.state
    assert (state.is_open, state.losses) == (False, 1)
    with pytest.raises(SerialPortError):  # stays given up; no silent reopen
        source.read_available()
    assert source.state.open_attempts == 1


def test_deliver_with_reconnect_disabled_ends_with_an_error(make_pty):
    pty = make_pty()
    sent = frames(range(1))

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path, reconnect=False))
        source.open()
        os.write(pty.master, wire(sent))
        got = bytearray()

        def consume(chunk: bytes) -> None:
            got.extend(chunk)
            if len(got) >= len(wire(sent)):
                pty.unplug()

        with pytest.raises(SerialPortError, match="lost") as info:
            await asyncio.wait_for(source.deliver(consume), DEADLINE_S)
        assert isinstance(info.value.__cause__, serial.SerialException)
        return bytes(got), source.state

    got, state = asyncio.run(scenario())
    assert StreamDecoder().feed(got) == sent
    assert (state.losses, state.open_attempts, state.is_open) == (1, 1, False)


def test_chunks_with_reconnect_disabled_ends_with_an_error(make_pty):
    pty = make_pty()
    sent = frames(range(1))

    async def scenario():
        source = SerialSource(SerialSettings(port=pty.path, reconnect=False))
        source.open()
        os.write(pty.master, wire(sent))
        got = b""
        with pytest.raises(SerialPortError, match="lost"):
            async for chunk in source.chunks():
                got += chunk
                if len(got) >= len(wire(sent)):
                    pty.unplug()
        return got, source.state

    got, state = asyncio.run(scenario())
    assert StreamDecoder().feed(got) == sent
    assert (state.losses, state.open_attempts, state.is_open) == (1, 1, False)


@READERS
def test_port_lost_backs_off_then_reconnects_when_the_symlink_returns(make_pty, tmp_path: Path, mode):
    """A /dev/serial/by-id/... path is a symlink that udev removes on unplug and
    recreates, pointing at a new tty, on replug; this plays that with ptys."""
    link = tmp_path / "usb-FTDI_board-if00-port0"
    first = make_pty()
    link.symlink_to(first.path)
    settings = SerialSettings(port=str(link), **FAST_BACKOFF)

    async def scenario():
        source = SerialSource(settings)
        consumer = Consumer(source, mode)
        await wait_until(lambda: source.state.is_open, "first open")
        os.write(first.master, wire(frames(range(0, 10))))
        await wait_until(lambda: len(consumer.frames) == 10, "frames before unplug")

        unplugged_at = time.monotonic()
        link.unlink()
        first.unplug()
        await wait_until(lambda: source.state.losses == 1, "loss noticed")
        lost = source.state
        assert not lost.is_open and "lost" in lost.last_error
        await wait_until(lambda: source.state.open_attempts >= 1 + 4, "four reopen attempts")
        await asyncio.sleep(0.2)
        waited_s = time.monotonic() - unplugged_at
        away = source.state

        second = make_pty()
        link.symlink_to(second.path)
        await wait_until(lambda: source.state.reconnects == 1, "reconnect")
        os.write(second.master, wire(frames(range(10, 20))))
        await wait_until(lambda: len(consumer.frames) == 20, "frames after replug")
        final = source.state
        await consumer.stop()
        return consumer, lost, away, waited_s, final

    consumer, lost, away, waited_s, final = asyncio.run(scenario())
    retries = away.open_attempts - 1
    # +1: a timer may fire a hair early and the boundary attempt land inside the window.
    assert retries <= max_attempts_within(settings, waited_s) + 1, (retries, waited_s)
    assert away.reads == lost.reads  # nothing read from a closed port
    assert not away.is_open
    assert "No such file or directory" in away.last_error and str(link) in away.last_error
    assert consumer.frames == frames(range(20))
    assert consumer.decoder.counters.samples_lost == 0
    assert (final.is_open, final.losses, final.reconnects) == (True, 1, 1)


def waiting_in(pty: Pty) -> int:
    """Bytes the pty's tty holds, not yet read by anyone (FIONREAD)."""
    return struct.unpack("i", fcntl.ioctl(pty.slave, termios.FIONREAD, b"\0" * 4))[0]


def test_wake_min_bytes_wakes_deliver_per_batch_and_read_pending_takes_the_rest(make_pty, tmp_path: Path):
    """With wake_min_bytes = 5 frames a tty wakes deliver() once 5 frames' bytes wait,
    and hands them over as one chunk (Linux gives a tty's bytes out 64 per read); fewer
    stay in the kernel until read_pending() takes them. A port reopened after a loss
    batches again."""
    link = tmp_path / "ttyBOARD"
    first = make_pty()
    link.symlink_to(first.path)
    frame = len(wire(frames(range(1))))
    settings = SerialSettings(port=str(link), wake_min_bytes=5 * frame, **FAST_BACKOFF)

    async def scenario():
        source = SerialSource(settings)
        chunks: list[bytes] = []
        task = asyncio.create_task(source.deliver(chunks.append))
        await wait_until(lambda: source.is_open, "port open")
        assert source.wake_min_bytes == 5 * frame > 64
        assert termios.tcgetattr(first.slave)[6][termios.VMIN] == 5 * frame
        os.write(first.master, wire(frames(range(0, 4))))
        await wait_until(lambda: waiting_in(first) == 4 * frame, "four frames in the tty")
        await asyncio.sleep(0.1)
        assert chunks == []  # below the batch: not woken
        taken = source.read_pending()
        assert source.read_pending() == b""  # nothing left: no bytes, and not a loss
        os.write(first.master, wire(frames(range(4, 9))))
        await wait_until(lambda: chunks, "woken by a whole batch")

        link.unlink()
        first.unplug()
        second = make_pty()
        link.symlink_to(second.path)
        await wait_until(lambda: source.state.reconnects == 1, "reconnect")
        vmin_again = termios.tcgetattr(second.slave)[6][termios.VMIN]
        os.write(second.master, wire(frames(range(9, 10))))
        await wait_until(lambda: waiting_in(second) == frame, "a frame in the new tty")
        await asyncio.sleep(0.1)
        woken_for_one = len(chunks) > 1
        late = source.read_pending()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        source.close()
        return taken, chunks, vmin_again, woken_for_one, late, source.state

    taken, chunks, vmin_again, woken_for_one, late, state = asyncio.run(scenario())
    assert taken == wire(frames(range(0, 4)))
    assert chunks == [wire(frames(range(4, 9)))]
    assert vmin_again == 5 * frame and not woken_for_one
    assert late == wire(frames(range(9, 10)))
    assert (state.losses, state.reconnects) == (1, 1)


def test_read_pending_on_a_quiet_tty_is_no_loss(make_pty):
    """pyserial leaves VMIN 0: a non-blocking read with nothing waiting returns no
    bytes instead of EAGAIN — which after a readiness report would mean end of file."""
    pty = make_pty()
    source = SerialSource(SerialSettings(port=pty.path))
    source.open()
    assert source.wake_min_bytes == 1
    assert source.read_pending() == b""
    os.write(pty.master, wire(frames(range(1))))
    deadline = time.monotonic() + DEADLINE_S
    got = b""
    while not got and time.monotonic() < deadline:
        got = source.read_pending()
    assert got == wire(frames(range(1)))
    assert (source.state.losses, source.is_open) == (0, True)
    source.close()


def test_wake_min_bytes_is_one_where_the_port_is_no_tty():
    opener = RecordingOpener()
    source = SerialSource(SerialSettings(port="loop://", wake_min_bytes=45), opener=opener)
    assert source.read_pending() == b""  # not open: nothing, and it stays closed
    source.open()
    assert source.wake_min_bytes == 1
    opener.ports[0].write(wire(frames(range(2))))
    assert source.read_pending() == wire(frames(range(2)))
    assert source.read_pending() == b""
    source.close()


def test_thread_reader_does_not_spin_while_the_port_is_away(make_pty, tmp_path: Path):
    link = tmp_path / "ttyBOARD"
    pty = make_pty()
    link.symlink_to(pty.path)
    settings = SerialSettings(port=str(link), **FAST_BACKOFF)
    source = SerialSource(settings)
    source.open()
    unplugged_at = time.monotonic()
    link.unlink()
    pty.unplug()

    calls = 0
    deadline = unplugged_at + DEADLINE_S
    while source.state.open_attempts < 1 + 4 and time.monotonic() < deadline:
        assert source.read(timeout_s=0.05) == b""
        calls += 1
    waited_s = time.monotonic() - unplugged_at
    state = source.state
    assert state.losses == 1 and state.open_attempts >= 5
    assert state.open_attempts - 1 <= max_attempts_within(settings, waited_s) + 1
    # Each call sleeps until the next attempt or its timeout: no tight loop.
    assert calls <= waited_s / 0.02 + state.open_attempts + 2, (calls, waited_s)

    second = make_pty()
    link.symlink_to(second.path)
    deadline = time.monotonic() + DEADLINE_S
    while not source.state.is_open and time.monotonic() < deadline:
        source.read(timeout_s=0.05)
    assert source.state.reconnects == 1
    os.write(second.master, wire(frames(range(5))))
    got = b""
    while len(got) < 75 and time.monotonic() < deadline:
        got += source.read(timeout_s=0.05)
    assert StreamDecoder().feed(got) == frames(range(5))
    source.close()
