"""CAN frame table, E2E protection against an independent bitwise oracle, and the DBC file."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import can_frames as cf
from drivers.can_frames import (
    COMMAND_FRAME,
    COUNTER_MAX,
    FRAMES,
    POSITION_FRAME,
    QUALITY_FRAME,
    VELOCITY_FRAME,
    AckResult,
    CyclicEncoder,
    check_command,
    crc8,
    e2e_p01_crc,
    encode_command,
)
from drivers.can_frames_text import dbc_text, frames_markdown
from drivers.published_values import Command, PublishedValues, StatusBits
from tests.can_helpers import candump_line, cantools_decode

ROOT = Path(__file__).resolve().parents[2]
DBC_PATH = ROOT / "config" / "adxl-gateway.dbc"
ENCODER = CyclicEncoder()


def encode_cyclic(values: PublishedValues, pos_counter: int, vel_counter: int, qual_counter: int = 0) -> dict:
    """The publisher's encoder, as {frame: payload}."""
    pos, vel, qual = ENCODER.encode(values, pos_counter, vel_counter, qual_counter)
    return {POSITION_FRAME: pos, VELOCITY_FRAME: vel, QUALITY_FRAME: qual}


# --------------------------------------------------------------------------- #
# Independent oracle: AUTOSAR Crc_CalculateCRC8 bit by bit, E2E_P01 as specified
# --------------------------------------------------------------------------- #
def autosar_crc8(data: bytes, start_value: int, is_first_call: bool) -> int:
    """SAE J1850 CRC-8 with the AUTOSAR call convention (continuation undoes the XOR)."""
    crc = 0xFF if is_first_call else start_value ^ 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def reference_p01_crc(data_id: int, payload: bytes) -> int:
    """E2E_P01Protect, DataIDMode BOTH, CRC in byte 0: data ID low, high, then the data."""
    crc = autosar_crc8(bytes([data_id & 0xFF]), 0xFF, False)
    crc = autosar_crc8(bytes([(data_id >> 8) & 0xFF]), crc, False)
    crc = autosar_crc8(bytes(payload[1:]), crc, False)
    return crc ^ 0xFF


def test_oracle_and_table_crc_match_the_catalogue_check_values() -> None:
    # reveng catalogue: CRC-8/SAE-J1850 check 0x4B; CRC-8/GSM-A (same poly, init 0) 0x37
    assert autosar_crc8(b"123456789", 0, True) == 0x4B
    assert crc8(b"123456789") == 0x4B
    assert crc8(b"123456789", init=0x00, xor_out=0x00) == 0x37


@settings(derandomize=True, deadline=None, max_examples=300)
@given(data_id=st.integers(0, 0xFFFF), payload=st.binary(min_size=2, max_size=8))
def test_e2e_crc_equals_the_bitwise_reference(data_id: int, payload: bytes) -> None:
    assert e2e_p01_crc(data_id, payload) == reference_p01_crc(data_id, payload)


@settings(derandomize=True, deadline=None, max_examples=200)
@given(code=st.integers(0, 255), counter=st.integers(0, COUNTER_MAX), bit=st.integers(0, 63))
def test_any_single_bit_error_in_a_command_frame_is_caught(code: int, counter: int, bit: int) -> None:
    good = bytearray(cf.pack(COMMAND_FRAME, {"Cmd_Code": code}))
    cf.e2e_p01_protect(COMMAND_FRAME, good, counter)
    bad = bytearray(good)
    bad[bit // 8] ^= 1 << (bit % 8)
    assert check_command(bytes(bad), None).problem is not None
    assert check_command(bytes(good), None).problem in (None, AckResult.UNKNOWN_COMMAND)


@settings(derandomize=True, deadline=None, max_examples=300)
@given(payload=st.binary(max_size=64), last=st.one_of(st.none(), st.integers(0, 15)))
def test_command_check_never_raises_on_any_bytes(payload: bytes, last: int | None) -> None:
    check = check_command(payload, last)
    assert (check.problem is None) == (check.command is not None)


def test_counter_runs_0_to_14_and_15_is_refused() -> None:
    sequence = [0]
    for _ in range(31):
        sequence.append(cf.next_counter(sequence[-1]))
    assert sequence[:16] == list(range(15)) + [0]
    with pytest.raises(ValueError):
        encode_command(Command.TARE, 15)
    forged = bytearray(cf.pack(COMMAND_FRAME, {"Cmd_Code": 1}))
    forged[1] = 0x0F
    forged[0] = reference_p01_crc(COMMAND_FRAME.data_id, forged)
    assert check_command(bytes(forged), None).problem is AckResult.COUNTER_ERROR


def test_command_check_outcomes() -> None:
    tare = encode_command(Command.TARE, 4)
    assert check_command(tare, None) == cf.CommandCheck(None, Command.TARE, 1, 4)
    assert check_command(tare, 4).problem is AckResult.COUNTER_ERROR  # repeated
    assert check_command(tare, 3).problem is None
    assert check_command(encode_command(9, 1), None).problem is AckResult.UNKNOWN_COMMAND
    assert check_command(tare[:3], None).problem is AckResult.BAD_LENGTH
    # a frame protected for another data ID (right layout, wrong identifier) fails
    wrong_id = bytearray(tare)
    wrong_id[0] = reference_p01_crc(POSITION_FRAME.data_id, wrong_id)
    assert check_command(bytes(wrong_id), None).problem is AckResult.CRC_ERROR


# --------------------------------------------------------------------------- #
# The DBC file
# --------------------------------------------------------------------------- #
def test_committed_dbc_is_the_generated_text() -> None:
    assert DBC_PATH.read_text(encoding="utf-8") == dbc_text(), (
        "config/adxl-gateway.dbc is out of date: write drivers.can_frames_text.dbc_text() to it"
    )


def test_dbc_loads_strictly_and_matches_the_table() -> None:
    db = cantools.database.load_file(str(DBC_PATH), strict=True)
    assert len(db.messages) == len(FRAMES)
    for frame in FRAMES:
        message = db.get_message_by_frame_id(frame.frame_id)
        assert message.name == frame.name
        assert message.length == frame.dlc
        assert not message.is_extended_frame
        assert message.senders == [frame.sender]
        assert message.cycle_time == frame.cycle_time_ms
        assert [s.name for s in message.signals] == [s.name for s in frame.signals]
        for spec in frame.signals:
            signal = message.get_signal_by_name(spec.name)
            assert (signal.start, signal.length, signal.is_signed) == (spec.start_bit, spec.length, spec.signed)
            assert signal.byte_order == "little_endian"
            assert signal.scale == pytest.approx(spec.factor, rel=1e-12)
            assert signal.offset == 0
            assert signal.receivers == [frame.receiver]


def test_every_frame_has_counter_and_crc_in_e2e_profile_1_places() -> None:
    for frame in FRAMES:
        crc, counter = frame.signals[0], frame.signals[1]
        assert (crc.start_bit, crc.length) == (0, 8) and crc.name.endswith("_CRC")
        assert (counter.start_bit, counter.length) == (8, 4) and counter.name.endswith("_Counter")


@settings(derandomize=True, deadline=None, max_examples=150)
@given(
    position=st.floats(-2000, 2000),
    velocity=st.floats(-2000, 2000),
    acceleration=st.floats(-30, 30),
    status=st.integers(0, 2**13 - 1),
    counter=st.integers(0, COUNTER_MAX),
)
def test_cantools_decodes_the_published_values(position, velocity, acceleration, status, counter) -> None:
    db = cantools.database.load_file(str(DBC_PATH))
    values = PublishedValues(
        position_m=position, velocity_mps=velocity, acceleration_mps2=acceleration, status=StatusBits(status)
    )
    frames = encode_cyclic(values, counter, counter)
    pos = db.decode_message(POSITION_FRAME.frame_id, frames[POSITION_FRAME])
    vel = db.decode_message(VELOCITY_FRAME.frame_id, frames[VELOCITY_FRAME])
    assert pos["Pos_Position"] == pytest.approx(position, abs=0.5e-6 + 1e-12)
    assert vel["Vel_Velocity"] == pytest.approx(velocity, abs=0.5e-6 + 1e-12)
    assert vel["Vel_Acceleration"] == pytest.approx(acceleration, abs=0.5e-3 + 1e-12)
    assert pos["Pos_Status"] == status
    assert (pos["Pos_Valid"], pos["Pos_Standstill"], pos["Pos_Stale"], pos["Pos_BoardLost"]) == tuple(
        int(bool(status & bit)) for bit in (1, 2, 4, 8)
    )
    for decoded, payload, frame in ((pos, frames[POSITION_FRAME], POSITION_FRAME),
                                    (vel, frames[VELOCITY_FRAME], VELOCITY_FRAME)):
        prefix = frame.signals[0].name.split("_")[0]
        assert decoded[f"{prefix}_Counter"] == counter
        assert decoded[f"{prefix}_CRC"] == reference_p01_crc(frame.frame_id, payload)


def test_missing_and_out_of_range_values() -> None:
    db = cantools.database.load_file(str(DBC_PATH))
    frames = encode_cyclic(PublishedValues(acceleration_mps2=50.0, status=StatusBits.VALID), 0, 0)
    pos = db.decode_message(0x120, frames[POSITION_FRAME])
    vel = db.decode_message(0x121, frames[VELOCITY_FRAME], decode_choices=False)
    assert str(pos["Pos_Position"]) == "NotAvailable"  # NaN position
    assert vel["Vel_Velocity"] == pytest.approx(-2147.483648)  # raw 0x80000000 without choices
    assert vel["Vel_Acceleration"] == pytest.approx(32.767)  # clamped ...
    assert pos["Pos_Status"] & StatusBits.SCALED_CLAMPED  # ... and flagged
    assert pos["Pos_Valid"] == 1


@pytest.mark.parametrize("value", [math.inf, -math.inf, 1e9, -1e9, 2147.4836475, -2147.4836476])
def test_values_beyond_the_range_are_clamped_and_flagged(value) -> None:
    db = cantools.database.load_file(str(DBC_PATH))
    frames = encode_cyclic(PublishedValues(position_m=value, velocity_mps=value, acceleration_mps2=value,
                                           status=StatusBits.VALID), 0, 0)
    pos = db.decode_message(0x120, frames[POSITION_FRAME])
    vel = db.decode_message(0x121, frames[VELOCITY_FRAME], decode_choices=False)
    top = 2147.483647
    assert pos["Pos_Position"] == pytest.approx(math.copysign(top, value))  # ±max, never the n/a raw value
    assert vel["Vel_Velocity"] == pytest.approx(math.copysign(top, value))
    assert vel["Vel_Acceleration"] == pytest.approx(math.copysign(32.767, value))
    assert pos["Pos_Status"] & StatusBits.SCALED_CLAMPED


@settings(derandomize=True, deadline=None, max_examples=200)
@given(raw=st.integers(-2**31 + 1, 2**31 - 2))
def test_halfway_between_two_steps_rounds_to_a_neighbour(raw) -> None:
    db = cantools.database.load_file(str(DBC_PATH))
    value = (raw + 0.5) * 1e-6
    frames = encode_cyclic(PublishedValues(position_m=value), 0, 0)
    decoded = db.decode_message(0x120, frames[POSITION_FRAME])["Pos_Position"]
    assert decoded in (pytest.approx(raw * 1e-6, abs=1e-9), pytest.approx((raw + 1) * 1e-6, abs=1e-9))


def test_cantools_command_line_decodes_candump_output() -> None:
    values = PublishedValues(position_m=1.234567, velocity_mps=-0.5, acceleration_mps2=0.25, status=StatusBits.VALID)
    frames = encode_cyclic(values, 7, 8)
    lines = [candump_line("vcan0", frame.frame_id, payload) for frame, payload in frames.items()]
    lines.append(candump_line("vcan0", COMMAND_FRAME.frame_id, encode_command(Command.TARE, 2)))
    out = cantools_decode(lines)
    assert len(out) == 4
    assert "ADXL_Position(" in out[0] and "Pos_Counter: 7" in out[0]
    assert float(re.search(r"Pos_Position: (\S+) m,", out[0]).group(1)) == pytest.approx(1.234567, abs=0.5e-6)
    assert "ADXL_Velocity(" in out[1] and "Vel_Counter: 8" in out[1]
    assert float(re.search(r"Vel_Velocity: (\S+) m/s,", out[1]).group(1)) == pytest.approx(-0.5, abs=0.5e-6)
    assert float(re.search(r"Vel_Acceleration: (\S+) m/s2\)", out[1]).group(1)) == pytest.approx(0.25, abs=0.5e-3)
    assert "ADXL_Quality(" in out[2] and "Qual_PositionStd: NotAvailable" in out[2]
    assert "ADXL_Command(" in out[3] and "Cmd_Code: TARE" in out[3]


# --------------------------------------------------------------------------- #
# The documentation
# --------------------------------------------------------------------------- #
DOCS = ROOT / "docs" / "can-frames.md"


def test_docs_embed_the_generated_frame_tables() -> None:
    assert frames_markdown() in DOCS.read_text(encoding="utf-8"), (
        "docs/can-frames.md is out of date: paste frames_markdown() into it"
    )


def test_worked_example_in_the_docs_is_right() -> None:
    text = DOCS.read_text(encoding="utf-8")
    frame = encode_command(Command.TARE, 0)
    assert f"cansend vcan0 130#{frame.hex().upper()}" in text
    covered = bytes.fromhex("30 01 00 01 00 00 00 00 00")  # data ID 0x0130 low, high, bytes 1..7
    assert covered[2:] == frame[1:]
    assert autosar_crc8(covered, 0xFF, False) ^ 0xFF == frame[0] == 0x3B
    assert "is 0x3B" in text


@settings(derandomize=True, deadline=None, max_examples=100)
@given(std=st.one_of(st.floats(0, 5000), st.just(math.nan), st.just(math.inf)),
       ext=st.integers(0, 2**6 - 1), counter=st.integers(0, COUNTER_MAX))
def test_cantools_decodes_the_quality_frame(std, ext, counter) -> None:
    """ADXL_Quality: the position's 1σ in µm (saturating, NaN = n/a) and the second status word."""
    from drivers.published_values import StatusExtBits

    db = cantools.database.load_file(str(DBC_PATH))
    values = PublishedValues(position_std_m=std, status_ext=StatusExtBits(ext), status=StatusBits.VALID)
    frame = encode_cyclic(values, 0, 0, counter)[QUALITY_FRAME]
    decoded = db.decode_message(QUALITY_FRAME.frame_id, frame)
    assert decoded["Qual_StatusExt"] == ext and decoded["Qual_Counter"] == counter and decoded["Qual_Valid"] == 1
    assert decoded["Qual_CRC"] == reference_p01_crc(QUALITY_FRAME.frame_id, frame)
    if math.isnan(std):
        assert str(decoded["Qual_PositionStd"]) == "NotAvailable"
    else:
        assert decoded["Qual_PositionStd"] == pytest.approx(min(std, 4294.967294), abs=0.5e-6 + 1e-12)
