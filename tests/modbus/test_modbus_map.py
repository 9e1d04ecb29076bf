"""The register map table, its printed forms and its encoding (no server here)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import modbus_map as mm
from drivers.modbus_map import (
    BY_NAME,
    INPUT_SIZE,
    MAP_VERSION,
    REGISTERS,
    RegType,
    ServerDiagnostics,
    Table,
    WordOrder,
    encode_input_registers,
)
from drivers.modbus_map_text import regmap_json, regmap_markdown, regmap_rows
from drivers.published_values import Command, PublishedValues, StatusBits

DOCS = Path(__file__).resolve().parents[2] / "docs" / "modbus-registers.md"

ORDERS = [WordOrder.ABCD, WordOrder.CDAB]


def _independent_decode(words: list[int], address: int, kind: str, order: WordOrder) -> float | int:
    """struct-based decoding written apart from the module under test."""
    if kind == "string32":
        return struct.pack(">16H", *words[address : address + 16]).rstrip(b"\0").decode("ascii")
    if kind in ("float32", "int32", "uint32"):
        pair = words[address : address + 2]
        if order is WordOrder.CDAB:
            pair = pair[::-1]
        raw = struct.pack(">HH", *pair)
        return struct.unpack({"float32": ">f", "int32": ">i", "uint32": ">I"}[kind], raw)[0]
    raw = struct.pack(">H", words[address])
    return struct.unpack(">h" if kind == "int16" else ">H", raw)[0]


# --------------------------------------------------------------------------- #
# The table itself
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("table", list(Table))
def test_each_table_is_contiguous_from_zero_without_overlap(table: Table) -> None:
    rows = sorted((r for r in REGISTERS if r.table is table), key=lambda r: r.address)
    expected_next = 0
    for row in rows:
        assert row.address == expected_next, f"{row.name} leaves a gap or overlaps"
        expected_next = row.address + row.words
    size = mm.INPUT_SIZE if table is Table.INPUT else mm.HOLDING_SIZE
    assert expected_next == size


def test_names_unique_and_word_counts_follow_type() -> None:
    assert len({r.name for r in REGISTERS}) == len(REGISTERS)
    for row in REGISTERS:
        expected = {RegType.FLOAT32: 2, RegType.INT32: 2, RegType.UINT32: 2, RegType.STRING32: 16}.get(row.type, 1)
        assert row.words == expected


def test_every_source_exists() -> None:
    value_fields = {f.name for f in dataclasses.fields(PublishedValues)}
    server_fields = {f.name for f in dataclasses.fields(ServerDiagnostics)}
    for row in REGISTERS:
        if row.table is Table.HOLDING:
            assert row.source.startswith("command.")
            Command[row.source.removeprefix("command.")]
        elif row.source.startswith("server."):
            assert row.source.removeprefix("server.") in server_fields
        else:
            assert row.source == "map_version" or row.source in value_fields, row.name
    # every command has its register, every PublishedValues number is published
    assert {r.source for r in REGISTERS if r.table is Table.HOLDING} == {f"command.{c.name}" for c in Command}
    published = {r.source for r in REGISTERS}
    assert value_fields <= published


def test_plc_reference_is_one_based_with_table_prefix() -> None:
    # Said once in the docs: wire addresses are 0-based, PLC notation 1-based.
    assert BY_NAME["MAP_VERSION"].address == 0 and BY_NAME["MAP_VERSION"].plc_reference == 30001
    assert BY_NAME["POSITION"].plc_reference == 30001 + BY_NAME["POSITION"].address
    assert BY_NAME["CMD_TARE"].address == 0 and BY_NAME["CMD_TARE"].plc_reference == 40001
    for row in REGISTERS:
        base = 30001 if row.table is Table.INPUT else 40001
        assert row.plc_reference == base + row.address


def test_map_version_is_bumped_when_the_table_changes() -> None:
    # A change to any row changes the fingerprint: bump MAP_VERSION, record the new
    # pair here, and tell the PLC integrators.
    canonical = json.dumps(
        [dataclasses.astuple(r) for r in REGISTERS], default=str, ensure_ascii=False
    ).encode()
    digest = hashlib.sha256(canonical).hexdigest()[:16]
    recorded = {1: "5848775e9570ad22", 2: "cb22d8cf81a6cc4f", 3: "ba3480037b35cb63", 4: "7c124a77b735dbb2"}
    assert MAP_VERSION in recorded, "MAP_VERSION bumped: record the new fingerprint here"
    assert digest == recorded[MAP_VERSION], (
        f"the register table changed (fingerprint {digest}): bump MAP_VERSION and record it"
    )


# --------------------------------------------------------------------------- #
# Printed forms
# --------------------------------------------------------------------------- #
def test_json_lists_every_row_with_the_documented_keys() -> None:
    rows = json.loads(regmap_json())
    assert rows == regmap_rows()
    assert [r["name"] for r in rows] == [r.name for r in REGISTERS]
    for printed, row in zip(rows, REGISTERS, strict=False):
        assert {"name", "table", "address", "type", "unit", "scale", "description"} <= printed.keys()
        assert printed["address"] == row.address
        assert printed["table"] in ("input", "holding")


def test_markdown_has_one_line_per_row_with_plc_reference() -> None:
    text = regmap_markdown()
    lines = [line for line in text.splitlines() if line.startswith("| 3") or line.startswith("| 4")]
    assert len(lines) == len(REGISTERS)
    for line, row in zip(lines, REGISTERS, strict=False):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[0] == str(row.plc_reference)
        assert cells[2] == str(row.address)
        assert cells[3] == row.name


def test_docs_embed_the_generated_table_verbatim() -> None:
    assert regmap_markdown() in DOCS.read_text(encoding="utf-8"), (
        "docs/modbus-registers.md is out of date: paste regmap_markdown() into it"
    )


# --------------------------------------------------------------------------- #
# Encoding against an independent decoder
# --------------------------------------------------------------------------- #
finite = st.floats(min_value=-2000.0, max_value=2000.0, allow_nan=False)


@settings(derandomize=True, deadline=None, max_examples=200)
@given(
    position=finite,
    velocity=finite,
    acceleration=finite,
    status=st.integers(0, 2**13 - 1),
    counter=st.integers(0, 2**40),
    temp=st.one_of(st.none(), st.floats(-40, 125)),
    age=st.one_of(st.none(), st.floats(0, 1e7)),
    order=st.sampled_from(ORDERS),
)
def test_encoding_round_trips_through_struct(
    position, velocity, acceleration, status, counter, temp, age, order
) -> None:
    values = PublishedValues(
        position_m=position,
        velocity_mps=velocity,
        acceleration_mps2=acceleration,
        status=StatusBits(status),
        heartbeat=counter,
        sample_counter=counter,
        last_sample_age_ms=age,
        bias_estimate_mps2=acceleration / 7,
        position_std_m=abs(position) / 1000,
        board_temp_c=temp,
        lost_samples=counter + 1,
        crc_errors=counter + 2,
        board_resets=counter + 3,
        can_send_errors=counter + 4,
    )
    words = encode_input_registers(values, ServerDiagnostics(requests=counter), order)
    assert len(words) == INPUT_SIZE and all(0 <= w <= 0xFFFF for w in words)

    def read(name: str) -> float | int:
        row = BY_NAME[name]
        return _independent_decode(words, row.address, str(row.type), order)

    for name, value in (("POSITION", position), ("VELOCITY", velocity), ("ACCELERATION", acceleration)):
        assert read(name) == float(np.float32(value))
    for name, value in (("POSITION_UM", position), ("VELOCITY_UM_S", velocity), ("ACCELERATION_UM_S2", acceleration)):
        assert abs(read(name) - value * 1e6) <= 0.5 + 1e-9 * abs(value * 1e6)
    assert read("STATUS") == status  # no clamping within ±2000 m
    assert read("HEARTBEAT") == counter % 2**16
    assert read("SAMPLE_COUNTER") == counter % 2**32
    assert read("LOST_SAMPLES") == (counter + 1) % 2**32
    assert read("CAN_SEND_ERRORS") == (counter + 4) % 2**32
    assert read("MODBUS_REQUESTS") == counter % 2**32
    assert read("MAP_VERSION") == MAP_VERSION
    assert read("BOARD_TEMPERATURE") == (-32768 if temp is None else round(temp * 100))
    expected_age = 0xFFFFFFFF if age is None else min(round(age), 0xFFFFFFFF)
    assert read("LAST_SAMPLE_AGE") == expected_age


@pytest.mark.parametrize("order", ORDERS)
def test_identity_registers_carry_version_and_device_name_in_any_word_order(order: WordOrder) -> None:
    diagnostics = ServerDiagnostics(version_major=3, version_minor=14, version_patch=159, device_name="line 4 / axis X")
    words = encode_input_registers(PublishedValues(), diagnostics, order)

    def read(name: str) -> float | int | str:
        row = BY_NAME[name]
        return _independent_decode(words, row.address, str(row.type), order)

    assert (read("VERSION_MAJOR"), read("VERSION_MINOR"), read("VERSION_PATCH")) == (3, 14, 159)
    assert read("DEVICE_NAME") == "line 4 / axis X"
    row = BY_NAME["DEVICE_NAME"]
    # first character in the high byte of the first register, whatever the 32-bit word order
    assert words[row.address] == (ord("l") << 8) | ord("i")
    assert mm.decode_register(row, words[row.address : row.address + row.words], order) == "line 4 / axis X"
    # 32 characters fill all 16 registers, longer names are cut (the config refuses them)
    full = encode_input_registers(PublishedValues(), ServerDiagnostics(device_name="x" * 40), order)
    assert full[row.address : row.address + 16] == [0x7878] * 16


def test_word_orders_are_each_others_swap() -> None:
    values = PublishedValues(position_m=-1.5, velocity_mps=0.25, sample_counter=0x12345678)
    abcd = encode_input_registers(values, word_order=WordOrder.ABCD)
    cdab = encode_input_registers(values, word_order=WordOrder.CDAB)
    for row in REGISTERS:
        if row.table is Table.INPUT and row.words == 2:
            a = row.address
            assert abcd[a : a + 2] == cdab[a : a + 2][::-1]
    row = BY_NAME["SAMPLE_COUNTER"]
    assert abcd[row.address : row.address + 2] == [0x1234, 0x5678]


def test_missing_numbers_are_nan_and_sentinels() -> None:
    words = encode_input_registers(PublishedValues())  # nothing measured yet
    for name in ("POSITION", "VELOCITY", "ACCELERATION", "BIAS_ESTIMATE", "POSITION_STD"):
        a = BY_NAME[name].address
        assert words[a : a + 2] == [0x7FC0, 0x0000]
        assert math.isnan(_independent_decode(words, a, "float32", WordOrder.ABCD))
    for name in ("POSITION_UM", "VELOCITY_UM_S", "ACCELERATION_UM_S2"):
        a = BY_NAME[name].address
        assert _independent_decode(words, a, "int32", WordOrder.ABCD) == -(2**31)
    assert _independent_decode(words, BY_NAME["BOARD_TEMPERATURE"].address, "int16", WordOrder.ABCD) == -32768
    assert _independent_decode(words, BY_NAME["LAST_SAMPLE_AGE"].address, "uint32", WordOrder.ABCD) == 2**32 - 1
    status = StatusBits(words[BY_NAME["STATUS"].address])
    assert StatusBits.VALID not in status and StatusBits.BOARD_LOST in status
    assert StatusBits.SCALED_CLAMPED not in status  # "not available" is not a clamp


@pytest.mark.parametrize("value, expected_raw", [(2200.0, 2**31 - 1), (-2200.0, -(2**31 - 1)), (math.inf, 2**31 - 1)])
def test_int32_clamps_and_flags_it_while_float_keeps_the_value(value: float, expected_raw: int) -> None:
    words = encode_input_registers(PublishedValues(velocity_mps=value, status=StatusBits.VALID))
    assert _independent_decode(words, BY_NAME["VELOCITY_UM_S"].address, "int32", WordOrder.ABCD) == expected_raw
    status = StatusBits(words[BY_NAME["STATUS"].address])
    assert StatusBits.SCALED_CLAMPED in status and StatusBits.VALID in status
    float_value = _independent_decode(words, BY_NAME["VELOCITY"].address, "float32", WordOrder.ABCD)
    if math.isfinite(value):
        assert float_value == value
    else:
        assert math.isnan(float_value)  # inf is not a number a PLC should compute with


def test_float_beyond_float32_range_is_nan() -> None:
    words = encode_input_registers(PublishedValues(position_std_m=1e39))
    assert math.isnan(_independent_decode(words, BY_NAME["POSITION_STD"].address, "float32", WordOrder.ABCD))


def test_decode_register_inverts_encode_register() -> None:
    for row in mm.INPUT_REGISTERS:
        if row.type in (RegType.BITFIELD, RegType.STRING32) or row.source == "map_version":
            continue
        for order in ORDERS:
            words, _ = mm.encode_register(row, 12.5, order)
            raw = mm.decode_register(row, words, order)
            expected = 12.5 if row.type is RegType.FLOAT32 else (
                round(12.5 / row.scale) if not row.wraps else 12
            )
            assert raw == expected, row.name
