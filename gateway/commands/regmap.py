"""adxlgw regmap: the Modbus register map, from the one table in drivers/modbus_map.py."""
from __future__ import annotations

import argparse
import sys

from drivers.modbus_map_text import regmap_json, regmap_markdown


def add_parser(sub) -> None:
    p = sub.add_parser("regmap", help="print the Modbus register map (Markdown, or --json)",
                       description="Print the register map: name, table, 0-based address, type, unit, scale, "
                                   "description; the Markdown form adds PLC notation (3xxxx/4xxxx).")
    p.add_argument("--json", action="store_true", help="JSON instead of a Markdown table")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    text = regmap_json() if args.json else regmap_markdown()
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return 0
