"""adxlgw config: print the default configuration, or check a file."""
from __future__ import annotations

import argparse
import sys

from gateway.config import default_config_text, load_config
from gateway.daemon.preflight import findings
from gateway.log_setup import error_prefix


def add_parser(sub) -> None:
    p = sub.add_parser("config", help="print the commented default config, or validate a config file",
                       description="With --default: print a complete, commented default configuration. "
                                   "With --check FILE: validate FILE, run every check `adxlgw run` makes "
                                   "before it starts (port set and present, drift-model file, Modbus host, "
                                   "CAN interface, the MQTT credentials and TLS CA files), and print the "
                                   "effective settings. Exit 2 if anything would stop or stall the daemon.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--default", action="store_true", help="print the default configuration (TOML)")
    g.add_argument("--check", metavar="FILE", help="validate FILE (exit 2 on problems, each on one line)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.default:
        sys.stdout.write(default_config_text())
        return 0
    cfg = load_config(args.check)  # a file that does not parse: one ConfigError, exit 2
    for section, keys in cfg.as_dict().items():
        for name, value in keys.items():
            print(f"{section}.{name} = {value!r}")
    problems = 0
    for finding in findings(cfg):
        if finding.severity == "note":
            print(f"adxlgw config: note: {finding.line(args.check)}", file=sys.stderr)
        else:
            problems += 1
            print(f"{error_prefix(sys.stderr)}adxlgw config: error: {finding.line(args.check)}", file=sys.stderr)
    if problems:
        return 2
    print(f"{args.check}: ok", file=sys.stderr)
    return 0
