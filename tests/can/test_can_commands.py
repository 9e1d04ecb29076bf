"""CAN commands to the publisher on python-can's virtual bus: E2E-protected frames, acknowledgements, refusals."""

from __future__ import annotations

import dataclasses
import logging

import cantools
import pytest

from drivers.can_frames import (
    ACK_FRAME,
    COMMAND_FRAME,
    POSITION_FRAME,
    AckResult,
    e2e_p01_crc,
    encode_command,
)
from drivers.can_publisher import CanPublisher
from drivers.published_values import Command, PublishedValues, StatusBits
from tests.can_helpers import DB, Peer, publishing, virtual_config
from tests.wire_helpers import Recorder, run


# --------------------------------------------------------------------------- #
# Commands
# --------------------------------------------------------------------------- #
async def exchange(peer: Peer, payload: bytes) -> dict:
    peer.send(COMMAND_FRAME.frame_id, payload)
    (ack,) = await peer.frames(1, ACK_FRAME.frame_id)
    decoded = DB.decode_message(ack.arbitration_id, ack.data, decode_choices=False)
    assert decoded["Ack_CRC"] == e2e_p01_crc(ACK_FRAME.frame_id, bytes(ack.data))
    return decoded


def test_tare_over_can_when_enabled(channel: str) -> None:
    recorder = Recorder()

    async def scenario() -> CanPublisher:
        async with publishing(virtual_config(channel, commands_enabled=True), recorder) as (publisher, peer):
            ack = await exchange(peer, encode_command(Command.TARE, 5))
            assert (ack["Ack_Result"], ack["Ack_Code"], ack["Ack_CommandCounter"]) == (AckResult.DONE, 1, 5)
            ack = await exchange(peer, encode_command(Command.REESTIMATE_BIAS, 6))
            assert ack["Ack_Result"] == AckResult.DONE
            assert ack["Ack_Counter"] == 1  # the acknowledgement has its own alive counter
            return publisher

    publisher = run(scenario())
    assert recorder.calls == [(Command.TARE, f"can:{channel}"), (Command.REESTIMATE_BIAS, f"can:{channel}")]
    assert publisher.counters.commands_accepted == 2 and publisher.counters.commands_rejected == 0


def test_commands_are_refused_when_disabled(channel: str) -> None:
    recorder = Recorder()

    async def scenario() -> CanPublisher:
        async with publishing(virtual_config(channel, commands_enabled=False), recorder) as (publisher, peer):
            ack = await exchange(peer, encode_command(Command.TARE, 0))
            assert ack["Ack_Result"] == AckResult.DISABLED
            return publisher

    publisher = run(scenario())
    assert recorder.calls == []
    assert publisher.counters.commands_rejected == 1


def test_corrupt_repeated_and_foreign_command_frames_are_refused(channel: str) -> None:
    recorder = Recorder()

    async def scenario() -> CanPublisher:
        async with publishing(virtual_config(channel, commands_enabled=True), recorder) as (publisher, peer):
            good = encode_command(Command.TARE, 9)
            corrupted = bytearray(good)
            corrupted[2] ^= 0x02  # TARE becomes code 3 on the wire, CRC unchanged
            assert (await exchange(peer, bytes(corrupted)))["Ack_Result"] == AckResult.CRC_ERROR
            assert (await exchange(peer, good[:4]))["Ack_Result"] == AckResult.BAD_LENGTH
            assert (await exchange(peer, encode_command(7, 1)))["Ack_Result"] == AckResult.UNKNOWN_COMMAND
            assert (await exchange(peer, good))["Ack_Result"] == AckResult.DONE
            assert (await exchange(peer, good))["Ack_Result"] == AckResult.COUNTER_ERROR  # replayed
            # the right bytes on another identifier or as an extended frame: not a command
            peer.send(0x131, encode_command(Command.TARE, 10))
            peer.send(COMMAND_FRAME.frame_id, encode_command(Command.TARE, 10), extended=True)
            # a later valid command is still served (and proves the two above were ignored)
            ack = await exchange(peer, encode_command(Command.TARE, 11))
            assert (ack["Ack_Result"], ack["Ack_CommandCounter"]) == (AckResult.DONE, 11)
            return publisher

    publisher = run(scenario())
    assert [c for c, _ in recorder.calls] == [Command.TARE, Command.TARE]
    assert publisher.counters.commands_rejected == 4
    assert publisher.counters.commands_accepted == 2


def test_an_older_command_frame_replayed_is_refused_and_a_restarted_sender_gets_back_in_step(channel: str) -> None:
    """The counter must advance by 1..MAX_COUNTER_DELTA: a TARE recorded and played again
    later lies behind and is refused (it used to set a new zero)."""
    recorder = Recorder()

    async def scenario() -> CanPublisher:
        async with publishing(virtual_config(channel, commands_enabled=True), recorder) as (publisher, peer):
            recorded = encode_command(Command.TARE, 4)
            assert (await exchange(peer, recorded))["Ack_Result"] == AckResult.DONE
            for counter in (5, 6, 7):
                assert (await exchange(peer, encode_command(Command.HINT_AT_REST, counter)))["Ack_Result"] \
                    == AckResult.DONE
            assert (await exchange(peer, recorded))["Ack_Result"] == AckResult.COUNTER_ERROR  # the replay
            # a jump beyond the window (two frames lost is the most tolerated) is refused ...
            assert (await exchange(peer, encode_command(Command.HINT_AT_REST, 12)))["Ack_Result"] \
                == AckResult.COUNTER_ERROR
            # ... and the sender's next frame, one ahead of it, puts it back in step (a restart)
            assert (await exchange(peer, encode_command(Command.HINT_AT_REST, 13)))["Ack_Result"] == AckResult.DONE
            assert (await exchange(peer, encode_command(Command.HINT_AT_REST, 14)))["Ack_Result"] == AckResult.DONE
            return publisher

    publisher = run(scenario())
    assert [c for c, _ in recorder.calls].count(Command.TARE) == 1
    assert publisher.counters.commands_rejected == 2


def test_refused_command_frames_are_logged_as_one_summary_per_interval(channel: str, caplog) -> None:
    async def scenario() -> None:
        async with publishing(virtual_config(channel, commands_enabled=False), Recorder()) as (publisher, peer):
            for k in range(300):
                peer.send(COMMAND_FRAME.frame_id, encode_command(Command.TARE, k % 15))
            await peer.frames(300, ACK_FRAME.frame_id)
            assert publisher.counters.commands_rejected == 300

    with caplog.at_level(logging.INFO, logger="drivers.can_publisher"):
        run(scenario())
    lines = [r.getMessage() for r in caplog.records if "refused: commands" in r.getMessage()]
    # the first at once, the 299 others counted in one line when the publisher stops
    assert len(lines) == 2 and "299 times" in lines[1], lines


@pytest.mark.parametrize("answer, expected", [(False, AckResult.DECLINED), (RuntimeError("bug"), AckResult.FAILED)])
def test_declined_or_failing_callback_is_acknowledged_and_survived(channel: str, answer, expected) -> None:
    recorder = Recorder(answer)

    async def scenario() -> CanPublisher:
        async with publishing(virtual_config(channel, commands_enabled=True), recorder) as (publisher, peer):
            assert (await exchange(peer, encode_command(Command.REESTIMATE_BIAS, 0)))["Ack_Result"] == expected
            await peer.frames(2, POSITION_FRAME.frame_id)  # still cycling
            assert publisher.running
            return publisher

    publisher = run(scenario())
    assert publisher.counters.commands_declined == 1
    assert len(recorder.calls) == 1


def test_two_gateways_share_one_bus_on_their_own_identifiers(channel: str) -> None:
    """can.base_id moves every frame: two publishers on one bus, each decoded with the DBC
    written for its identifiers, and a command to one is answered by that one only."""
    from drivers.can_frames import frame_table
    from drivers.can_frames_text import dbc_text

    tables = (frame_table(0x120), frame_table(0x200))
    received: list = [[], []]

    async def scenario() -> list:
        configs = [dataclasses.replace(virtual_config(channel, commands_enabled=True), frames=t) for t in tables]
        async with (
            publishing(configs[0], on_command=lambda c, s: received[0].append(c) or True) as (first, peer),
            publishing(configs[1], on_command=lambda c, s: received[1].append(c) or True) as (second, _),
        ):
            first.update(PublishedValues(position_m=1.5, status=StatusBits.VALID))
            second.update(PublishedValues(position_m=-2.25, status=StatusBits.VALID))
            frames = await peer.frames(40)
            peer.send(tables[1].command.frame_id, encode_command(Command.TARE, 1, tables[1]))
            acks = await peer.frames(1, tables[1].ack.frame_id)
            return frames, acks

    frames, acks = run(scenario())
    dbs = [cantools.database.load_string(dbc_text(t), database_format="dbc") for t in tables]
    seen = {}
    for message in frames:
        for db, table in zip(dbs, tables, strict=False):
            if message.arbitration_id == table.position.frame_id:
                seen[table.base_id] = db.decode_message(message.arbitration_id, message.data)["Pos_Position"]
    assert seen == {0x120: pytest.approx(1.5), 0x200: pytest.approx(-2.25)}
    assert received == [[], [Command.TARE]]
    ack = dbs[1].decode_message(acks[0].arbitration_id, acks[0].data)
    assert ack["Ack_Result"] == "DONE"
    # a frame under the other gateway's identifier fails the E2E check (data ID = identifier)
    from drivers.can_frames import check_command
    assert check_command(encode_command(Command.TARE, 1, tables[1]), None, tables[0]).problem == AckResult.CRC_ERROR
