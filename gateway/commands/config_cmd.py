"""adxlgw config: print the default configuration, or check a file."""
from __future__ import annotations

import argparse
import sys

from gateway.config import default_config_text, load_config


def add_parser(sub) -> None:
    p = sub.add_parser("config", help="print the commented default config, or validate a config file",
                       description="With --default: print a complete, commented default configuration. "
                                   "With --check FILE: validate FILE and print the effective settings.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--default", action="store_true", help="print the default configuration (TOML)")
    g.add_argument("--check", metavar="FILE", help="validate FILE (exit 2 on the first problem)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.default:
        sys.stdout.write(default_config_text())
        return 0
    cfg = load_config(args.check)
    for section, keys in cfg.as_dict().items():
        for name, value in keys.items():
            print(f"{section}.{name} = {value!r}")
    print(f"{args.check}: ok", file=sys.stderr)
    return 0
