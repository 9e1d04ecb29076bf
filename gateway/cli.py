"""`adxlgw` — the gateway's one command, with subcommands.

Exit codes: 0 ok · 1 internal error (bug) · 2 bad input (arguments, config, recording)
· 3 device unusable with --once · 130 interrupted.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from importlib import metadata

from gateway.errors import GatewayError
from gateway.log_setup import configure_logging, error_prefix

log = logging.getLogger("adxlgw")

# subcommand → its module, in the order `adxlgw --help` lists them
COMMAND_MODULES = {
    "demo": "demo",
    "run": "run",
    "simulate": "simulate",
    "emulate": "emulate",
    "record": "record",
    "import": "import_csv",
    "fit-drift": "fit_drift",
    "estimate": "estimate",
    "diagnose": "diagnose",
    "fleet": "fleet",
    "config": "config_cmd",
    "regmap": "regmap",
    "dbc": "dbc",
    "install-files": "install_files",
}


def version() -> str:
    try:
        return metadata.version("adxl-gateway")
    except metadata.PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def chosen_command(argv: list[str]) -> str | None:
    """The subcommand named on the command line, if it is one of ours (options before it
    take no values)."""
    for arg in argv:
        if not arg.startswith("-"):
            return arg if arg in COMMAND_MODULES else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every subcommand, or with `only` of that one: each subcommand's
    module imports what it needs (the simulator, scipy.stats, the diagnosis…), and the
    daemon started by systemd — after a crash too, while a PLC sees no answer — should
    not wait for the offline tools' imports (about half a second)."""
    parser = argparse.ArgumentParser(
        prog="adxlgw",
        description="ADXL202/8051 accelerometer gateway: distance and velocity over Modbus and CAN.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action="version", version=f"adxlgw {version()}")
    # not required here: `adxlgw --foo` must say --foo is unknown, not that a command is missing (main)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command, name in COMMAND_MODULES.items():
        if only is None or command == only:
            importlib.import_module(f"gateway.commands.{name}").add_parser(sub)
    return parser


def warn_if_not_compiled() -> None:
    """Once per process: numba was wanted but could not start (gateway/core/jit.py)."""
    from gateway.core import jit

    if jit.JIT_UNAVAILABLE_REASON:
        log.warning("%s. The estimators run as plain Python: same numbers, more CPU (docs/daemon.md)",
                    jit.JIT_UNAVAILABLE_REASON.rstrip("."))


def main(argv: list[str] | None = None) -> int:
    # logging first: the subcommands' imports may already have something to say
    configure_logging(sys.stderr)
    warn_if_not_compiled()
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(only=chosen_command(argv))
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.command is None:
        parser.error(f"no command given: one of {', '.join(COMMAND_MODULES)} (adxlgw --help)")
    if args.verbose:
        logging.getLogger().setLevel(logging.DEBUG)
    try:
        return int(args.run(args) or 0)
    except GatewayError as err:
        print(f"{error_prefix(sys.stderr)}adxlgw {args.command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
