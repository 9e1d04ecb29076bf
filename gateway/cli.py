"""`adxlgw` — the gateway's one command, with subcommands.

Exit codes: 0 ok · 1 internal error (bug) · 2 bad input (arguments, config, recording)
· 3 device unusable with --once · 130 interrupted.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from gateway.errors import GatewayError

# subcommand modules in the order `adxlgw --help` lists them
COMMAND_MODULES = (
    "demo",
    "run",
    "simulate",
    "emulate",
    "record",
    "import_csv",
    "fit_drift",
    "estimate",
    "diagnose",
    "config_cmd",
    "regmap",
    "dbc",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="adxlgw",
        description="ADXL202/8051 accelerometer gateway: distance and velocity over Modbus and CAN.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        module = importlib.import_module(f"gateway.commands.{name}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return int(args.run(args) or 0)
    except GatewayError as err:
        print(f"adxlgw {args.command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
