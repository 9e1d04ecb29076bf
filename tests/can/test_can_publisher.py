"""The CAN publisher on python-can's virtual bus: cyclic frames and send failures (commands: test_can_commands.py)."""

from __future__ import annotations

import asyncio
import re
import time

import can
import pytest
from can.interfaces import virtual

from drivers.can_frames import (
    COUNTER_MAX,
    POSITION_FRAME,
    QUALITY_FRAME,
    VELOCITY_FRAME,
    e2e_p01_crc,
)
from drivers.can_publisher import CanPublisher, CanPublisherConfig, CanPublisherError
from drivers.published_values import PublishedValues, StatusBits
from tests.can_helpers import DB, VALUES, candump_line, cantools_decode, publishing, virtual_config
from tests.wire_helpers import run


# --------------------------------------------------------------------------- #
# Cyclic frames
# --------------------------------------------------------------------------- #
def test_cyclic_frames_carry_the_values_with_counter_and_crc(channel: str) -> None:
    async def scenario() -> tuple[list[can.Message], CanPublisher]:
        async with publishing(virtual_config(channel)) as (publisher, peer):
            return await peer.frames(3 * 20), publisher

    messages, publisher = run(scenario())
    by_id: dict[int, list[can.Message]] = {}
    for message in messages:
        by_id.setdefault(message.arbitration_id, []).append(message)
    prefixes = {POSITION_FRAME.frame_id: "Pos", VELOCITY_FRAME.frame_id: "Vel", QUALITY_FRAME.frame_id: "Qual"}
    assert set(by_id) == set(prefixes)
    for frame_id, frames in by_id.items():
        prefix = prefixes[frame_id]
        counters = []
        for message in frames:
            assert not message.is_extended_id and message.dlc == 8
            decoded = DB.decode_message(frame_id, message.data)
            counters.append(decoded[f"{prefix}_Counter"])
            assert decoded[f"{prefix}_CRC"] == e2e_p01_crc(frame_id, bytes(message.data))
            assert decoded[f"{prefix}_Valid"] == 1 and decoded[f"{prefix}_BoardLost"] == 0
            if prefix == "Pos":
                assert decoded["Pos_Position"] == pytest.approx(VALUES.position_m, abs=0.5e-6)
                assert decoded["Pos_Status"] == int(VALUES.status)
            elif prefix == "Vel":
                assert decoded["Vel_Velocity"] == pytest.approx(VALUES.velocity_mps, abs=0.5e-6)
                assert decoded["Vel_Acceleration"] == pytest.approx(VALUES.acceleration_mps2, abs=0.5e-3)
            else:
                assert decoded["Qual_PositionStd"] == pytest.approx(VALUES.position_std_m, abs=0.5e-6)
                assert decoded["Qual_StatusExt"] == int(VALUES.status_ext)
        # alive counter: starts at 0, +1 per frame, 0..14 (E2E profile 1)
        assert counters[0] == 0
        assert all(b == (a + 1) % (COUNTER_MAX + 1) for a, b in zip(counters, counters[1:], strict=False)), counters
        assert max(counters) == COUNTER_MAX
    assert publisher.counters.frames_sent >= 60 and publisher.counters.send_errors == 0


def test_new_values_appear_in_the_next_cycles(channel: str) -> None:
    async def scenario() -> None:
        async with publishing(virtual_config(channel)) as (publisher, peer):
            await peer.frames(2, POSITION_FRAME.frame_id)
            publisher.update(PublishedValues(position_m=-12.5, status=StatusBits.STALE))
            deadline = time.monotonic() + 5
            while True:
                (message,) = await peer.frames(1, POSITION_FRAME.frame_id)
                decoded = DB.decode_message(message.arbitration_id, message.data)
                if decoded["Pos_Position"] == pytest.approx(-12.5):
                    assert decoded["Pos_Stale"] == 1 and decoded["Pos_Valid"] == 0
                    return
                assert time.monotonic() < deadline

    run(scenario())


def test_the_period_is_kept_and_a_stalled_loop_resynchronises(channel: str) -> None:
    async def scenario() -> None:
        async with publishing(virtual_config(channel, period_ms=10)) as (publisher, peer):
            await peer.frames(1, POSITION_FRAME.frame_id)
            started = time.monotonic()
            await peer.frames(10, POSITION_FRAME.frame_id)
            elapsed = time.monotonic() - started
            # 10 cycles of 10 ms: not faster than the schedule allows (no burst), and
            # not grossly slower (generous bound: the machine is shared)
            assert 0.08 < elapsed < 1.0, elapsed
            late_before = publisher.counters.cycles_late
            time.sleep(0.1)  # block the event loop for ten periods
            await peer.frames(2, POSITION_FRAME.frame_id)
            assert publisher.counters.cycles_late - late_before >= 5

    run(scenario())


def test_candump_of_real_frames_decodes_with_the_cantools_cli(channel: str) -> None:
    async def scenario() -> list[can.Message]:
        async with publishing(virtual_config(channel)) as (_, peer):
            return await peer.frames(6)

    messages = run(scenario())
    lines = [candump_line("vcan0", m.arbitration_id, bytes(m.data)) for m in messages]
    out = cantools_decode(lines)
    assert len(out) == 6
    positions = [float(v) for line in out for v in re.findall(r"Pos_Position: (\S+) m,", line)]
    velocities = [float(v) for line in out for v in re.findall(r"Vel_Velocity: (\S+) m/s,", line)]
    assert positions == pytest.approx([VALUES.position_m] * 2, abs=0.5e-6)
    assert velocities == pytest.approx([VALUES.velocity_mps] * 2, abs=0.5e-6)


def test_update_can_send_at_once_when_min_interval_is_set(channel: str) -> None:
    async def scenario() -> None:
        config = virtual_config(channel, period_ms=2000, min_interval_ms=0)
        async with publishing(config) as (publisher, peer):
            await peer.frames(1, POSITION_FRAME.frame_id)  # the cycle's first transmission
            sent_at = time.monotonic()
            publisher.update(PublishedValues(position_m=2.0, status=StatusBits.VALID))
            (message,) = await peer.frames(1, POSITION_FRAME.frame_id, timeout_s=1.0)
            # long before the next 2 s cycle
            assert time.monotonic() - sent_at < 1.0
            assert DB.decode_message(message.arbitration_id, message.data)["Pos_Position"] == 2.0

    run(scenario())


class RecordingBus(virtual.VirtualBus):
    """A virtual bus that notes each ADXL_Position frame sent: when, whether the sender
    was inside CanPublisher.update() at the time, its position and alive counter."""

    inside_update = False
    sends: list[tuple[float, bool, float, int]] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == POSITION_FRAME.frame_id:
            decoded = DB.decode_message(msg.arbitration_id, msg.data)
            RecordingBus.sends.append(
                (time.monotonic(), RecordingBus.inside_update, decoded["Pos_Position"], decoded["Pos_Counter"])
            )
        super().send(msg, timeout)


def recording_factory(**kwargs) -> can.BusABC:
    kwargs.pop("interface")
    RecordingBus.sends = []
    return RecordingBus(**kwargs)


def sent_between(start: float, end: float) -> list[tuple[float, bool, float, int]]:
    return [s for s in RecordingBus.sends if start <= s[0] < end]


async def feed_updates(publisher: CanPublisher, every_s: float, duration_s: float) -> None:
    """update() with position = k mm every `every_s` (like the daemon per sample)."""
    k = 0
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        k += 1
        RecordingBus.inside_update = True
        publisher.update(PublishedValues(position_m=k / 1000, status=StatusBits.VALID))
        RecordingBus.inside_update = False
        await asyncio.sleep(every_s)


def test_frames_follow_the_updates_once_per_period_with_the_newest_values(channel: str) -> None:
    """The default: each cycle's frames go out inside the first update() at or after
    their due time, carrying that update's values; one transmission per period."""
    async def scenario() -> tuple[list, float]:
        config = virtual_config(channel, period_ms=50)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            await asyncio.sleep(0.12)  # no updates yet: the timer keeps the cycle
            started = time.monotonic()
            await feed_updates(publisher, every_s=0.005, duration_s=1.0)
            ended = time.monotonic()
            return sent_between(started, ended), ended - started

    sends, elapsed = run(scenario())
    on_update = [s for s in sends if s[1]]
    # nearly all sent from update() (the timer only when the loop overslept by 25 ms),
    # each carrying the values of the update it was sent in (position k mm, k ≥ 1)
    assert len(on_update) >= 0.8 * len(sends), sends
    assert all(position >= 0.001 for _, _, position, _ in on_update)
    # one transmission per period: never more than the drift-free schedule allows
    assert len(sends) <= elapsed / 0.050 + 1, (len(sends), elapsed)
    assert len(sends) >= 0.5 * elapsed / 0.050, (len(sends), elapsed)
    gaps = [b[0] - a[0] for a, b in zip(sends, sends[1:], strict=False)]
    assert min(gaps) >= 0.025 - 0.002, gaps  # at least half a period apart
    counters = [c for *_, c in sends]
    assert all(b == (a + 1) % (COUNTER_MAX + 1) for a, b in zip(counters, counters[1:], strict=False)), counters


@pytest.mark.parametrize("offset", [0.0, 0.25, 0.5, 0.75])
def test_updates_once_per_period_lock_the_cycle_whatever_their_phase(channel: str, offset: float) -> None:
    """The daemon woken once per batch of samples updates about once per period. Each
    update must carry a cycle, whatever its phase against the schedule; a due time
    just after the updates would otherwise leave every cycle to the timer (a wakeup
    of its own) and the frames half a period old."""
    period_s = 0.040

    async def scenario() -> tuple[list, float]:
        config = virtual_config(channel, period_ms=period_s * 1000)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            await asyncio.sleep(period_s * (2 + offset))
            next_at = time.monotonic()
            for k in range(40):  # strictly periodic: no drift to unlock a bad phase
                await asyncio.sleep(max(0.0, next_at - time.monotonic()))
                RecordingBus.inside_update = True
                publisher.update(PublishedValues(position_m=(k + 1) / 1000, status=StatusBits.VALID))
                RecordingBus.inside_update = False
                next_at += period_s
            return RecordingBus.sends, next_at - 40 * period_s

    sends, started = run(scenario())
    locked = [s for s in sends if s[0] >= started + 4 * period_s]  # a few cycles to lock on
    # 36 cycles after the lock-on window; a loaded machine delays some updates into one cycle
    assert len(locked) >= 25, sends
    assert sum(on_update for _, on_update, _, _ in locked) >= 0.9 * len(locked), locked
    gaps = [b[0] - a[0] for a, b in zip(sends, sends[1:], strict=False)]
    assert min(gaps) >= period_s / 2 - 0.002, gaps
    elapsed = sends[-1][0] - sends[0][0]
    assert len(sends) <= elapsed / period_s + 2, (len(sends), elapsed)


def test_an_update_from_inside_a_transmission_starts_no_second_one(channel: str) -> None:
    """The daemon's values function may take newer board bytes and publish them —
    update() from inside the transmission that asked for the values. That update is
    carried by this transmission; it must not start another (nor recurse)."""
    async def scenario() -> list:
        config = virtual_config(channel, period_ms=20)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            built = [0]

            def build() -> PublishedValues:
                built[0] += 1
                publisher.update(build)  # what Gateway.values does when it finds new bytes
                return PublishedValues(position_m=built[0] / 1000, status=StatusBits.VALID)

            for _ in range(100):
                publisher.update(build)
                await asyncio.sleep(0.002)
            return RecordingBus.sends

    sends = run(scenario())
    assert 5 <= len(sends) <= 0.2 / 0.020 * 1.5 + 2, sends
    counters = [c for *_, c in sends]
    assert all(b == (a + 1) % (COUNTER_MAX + 1) for a, b in zip(counters, counters[1:], strict=False)), counters


def test_without_updates_the_timer_keeps_the_cycle_and_the_counter_going(channel: str) -> None:
    async def scenario() -> tuple[list, float, float]:
        config = virtual_config(channel, period_ms=20)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            await feed_updates(publisher, every_s=0.002, duration_s=0.2)
            stopped = time.monotonic()  # the board falls silent
            await asyncio.sleep(0.4)
            return RecordingBus.sends, stopped, time.monotonic()

    sends, stopped, ended = run(scenario())
    after = [s for s in sends if stopped <= s[0] < ended]
    # one per period (20 ms) on average, no burst; the first within 1.5 periods
    assert 0.4 / 0.020 * 0.5 <= len(after) <= 0.4 / 0.020 + 1, len(after)
    assert after[0][0] - stopped <= 0.030 + 0.010
    counters = [c for *_, c in sends]
    assert all(b == (a + 1) % (COUNTER_MAX + 1) for a, b in zip(counters, counters[1:], strict=False)), counters


def test_values_given_as_a_function_are_built_once_per_transmission(channel: str) -> None:
    calls: list[int] = []

    def build() -> PublishedValues:
        calls.append(1)
        return PublishedValues(position_m=1.25, status=StatusBits.VALID)

    async def scenario() -> tuple[int, int, list[can.Message]]:
        async with publishing(virtual_config(channel, period_ms=20)) as (publisher, peer):
            await peer.frames(1, POSITION_FRAME.frame_id)
            before, sent_before = len(calls), publisher.counters.frames_sent
            for _ in range(200):  # updates between two due times: at most one transmission
                publisher.update(build)
            burst = len(calls) - before
            frames = await peer.frames(3, POSITION_FRAME.frame_id)
            await publisher.stop()
            return burst, len(calls), publisher.counters.frames_sent - sent_before, frames

    burst, built, sent, frames = run(scenario())
    assert burst <= 1
    assert built == sent // 3  # once per cycle (three frames), none in between
    assert DB.decode_message(POSITION_FRAME.frame_id, frames[-1].data)["Pos_Position"] == 1.25


def test_strictly_cyclic_frames_never_go_out_from_update(channel: str) -> None:
    async def scenario() -> list:
        config = virtual_config(channel, period_ms=20, sync_to_updates=False)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            await feed_updates(publisher, every_s=0.002, duration_s=0.3)
            return list(RecordingBus.sends)

    sends = run(scenario())
    assert len(sends) >= 5
    assert not any(inside for _, inside, *_ in sends)


def test_min_interval_sends_on_update_at_most_that_often(channel: str) -> None:
    """Mixed mode: update() sends when min_interval_ms has passed since the last
    transmission, more often than the period."""
    async def scenario() -> tuple[list, float]:
        config = virtual_config(channel, period_ms=200, min_interval_ms=20)
        async with publishing(config, bus_factory=recording_factory) as (publisher, _):
            await asyncio.sleep(0.05)
            started = time.monotonic()
            await feed_updates(publisher, every_s=0.005, duration_s=0.6)
            return [s for s in RecordingBus.sends if s[0] >= started], time.monotonic() - started

    sends, elapsed = run(scenario())
    gaps = [b[0] - a[0] for a, b in zip(sends, sends[1:], strict=False)]
    assert min(gaps) >= 0.020 - 0.001, gaps
    assert len(sends) > elapsed / 0.200 * 3  # far more than one per 200 ms period
    assert sum(inside for _, inside, *_ in sends) >= 0.8 * len(sends)


# --------------------------------------------------------------------------- #
# Send failures
# --------------------------------------------------------------------------- #
class FlakyBus(virtual.VirtualBus):
    """A virtual bus whose send fails for a while (buffer full, bus off …)."""

    failures: list[Exception] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.failures:
            raise self.failures.pop(0)
        super().send(msg, timeout)


def test_failing_sends_are_counted_and_the_cycle_goes_on(channel: str, caplog) -> None:
    failures = [can.CanOperationError("Transmit buffer full")] * 6 + [OSError("network is down")]

    def factory(**kwargs) -> can.BusABC:
        kwargs.pop("interface")
        bus = FlakyBus(**kwargs)
        bus.failures = list(failures)
        return bus

    async def scenario() -> CanPublisher:
        config = virtual_config(channel, send_error_log_interval_s=60)
        async with publishing(config, bus_factory=factory) as (publisher, peer):
            frames = await peer.frames(6)
            assert publisher.running
            counters = [DB.decode_message(m.arbitration_id, m.data) for m in frames]
            # frames that failed still advanced the counter: receivers see the gap
            first_position = next(c for c in counters if "Pos_Counter" in c)
            assert first_position["Pos_Counter"] >= 3
            return publisher

    caplog.set_level("WARNING", logger="drivers.can_publisher")
    publisher = run(scenario())
    assert publisher.counters.send_errors == len(failures)
    assert publisher.counters.frames_sent >= 6
    # rate-limited: one report for the burst, not one per failure
    reports = [r for r in caplog.records if "CAN send failed" in r.getMessage()]
    assert len(reports) == 1


def test_unknown_interface_raises_can_publisher_error(channel: str) -> None:
    async def scenario() -> None:
        publisher = CanPublisher(CanPublisherConfig(interface="no-such-interface", channel=channel))
        with pytest.raises(CanPublisherError):
            await publisher.start()
        assert not publisher.running

    run(scenario())


@pytest.mark.parametrize("overrides", [{"period_ms": 0}, {"period_ms": 10, "min_interval_ms": 20},
                                       {"period_ms": 10, "min_interval_ms": -1}])
def test_config_validation(overrides: dict) -> None:
    with pytest.raises(CanPublisherError):
        CanPublisherConfig(**overrides)


def test_stop_is_quick_and_releases_the_channel(channel: str) -> None:
    async def scenario() -> None:
        publisher = CanPublisher(virtual_config(channel))
        await publisher.start()
        assert channel in virtual.channels
        await asyncio.sleep(0.05)
        started = time.monotonic()
        await publisher.stop()
        assert time.monotonic() - started < 2.0
        assert channel not in virtual.channels
        assert not publisher.running

    run(scenario())
