"""adxlgw dbc: the DBC file describing every CAN frame the gateway sends and accepts."""
from __future__ import annotations

import argparse
import sys

from drivers.can_frames import frame_table
from drivers.can_frames_text import dbc_text


def add_parser(sub) -> None:
    p = sub.add_parser("dbc", help="print the DBC file of the gateway's CAN frames",
                       description="Print the DBC text (the same as config/adxl-gateway.dbc for the default "
                                   "identifiers; with --config, for that file's can.base_id). Decode live "
                                   "traffic with: candump vcan0 | python -m cantools decode FILE.dbc")
    p.add_argument("--config", metavar="FILE", help="the gateway's TOML config: its CAN identifiers")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.config:
        from gateway.config import load_config

        table = frame_table(load_config(args.config).can.base_id)
    else:
        table = frame_table()
    sys.stdout.write(dbc_text(table))
    return 0
