"""adxlgw dbc: the DBC file describing every CAN frame the gateway sends and accepts."""
from __future__ import annotations

import argparse
import sys

from drivers.can_frames import dbc_text


def add_parser(sub) -> None:
    p = sub.add_parser("dbc", help="print the DBC file of the gateway's CAN frames",
                       description="Print the DBC text (the same as config/adxl-gateway.dbc). Decode live "
                                   "traffic with: candump vcan0 | python -m cantools decode FILE.dbc")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    sys.stdout.write(dbc_text())
    return 0
