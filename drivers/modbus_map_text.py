"""The Modbus register map as text: the JSON `adxlgw regmap --json` prints and the Markdown
table docs/modbus-registers.md embeds (tests/modbus/test_modbus_map.py keeps it equal), both made
from drivers/modbus_map.REGISTERS."""

from __future__ import annotations

import json

from .modbus_map import MAP_VERSION, REGISTERS


def regmap_rows() -> list[dict[str, object]]:
    """The table as JSON-able dicts (what `adxlgw regmap --json` prints)."""
    return [
        {
            "name": r.name,
            "table": str(r.table),
            "address": r.address,
            "plc_reference": r.plc_reference,
            "type": str(r.type),
            "words": r.words,
            "unit": r.unit,
            "scale": r.scale,
            "description": r.description,
        }
        for r in REGISTERS
    ]


def regmap_json() -> str:
    return json.dumps(regmap_rows(), indent=2, ensure_ascii=False) + "\n"


def regmap_markdown() -> str:
    """The table in Markdown with PLC notation (embedded verbatim in the docs)."""
    lines = [
        f"Register map version {MAP_VERSION}. Address = 0-based address on the wire; "
        "PLC = 1-based PLC reference (30001 + address for input registers, "
        "40001 + address for holding registers). Value in the named unit = raw × scale.",
        "",
        "| PLC | Table | Address | Name | Type | Words | Unit | Scale | Description |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in REGISTERS:
        lines.append(
            f"| {r.plc_reference} | {r.table} | {r.address} | {r.name} | {r.type} "
            f"| {r.words} | {r.unit} | {r.scale:g} | {r.description} |"
        )
    return "\n".join(lines) + "\n"
