"""adxlgw install-files: the files a deployment needs beside the package, from the package.

The wheel carries the systemd unit, the DBC and docs/daemon.md as package data
(gateway/data/); the default configuration is generated from the config schema of
this very installation, so it always lists the keys this version knows.
"""
from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from gateway.config import default_config_text
from gateway.errors import InputError

UNIT_NAME = "adxl-gateway.service"
# where the shipped unit expects the program; replaced by this installation's path
SHIPPED_EXEC = "/opt/adxl-gateway/venv/bin/adxlgw"


def packaged_text(name: str) -> str:
    return (resources.files("gateway") / "data" / name).read_text(encoding="utf-8")


def installed_program() -> str:
    """The adxlgw script beside this interpreter (a venv's bin/), else the shipped path."""
    candidate = Path(sys.executable).parent / "adxlgw"
    return str(candidate) if candidate.is_file() else SHIPPED_EXEC


def unit_text() -> str:
    return packaged_text(UNIT_NAME).replace(SHIPPED_EXEC, installed_program())


FILES = {
    # name for --print: (path under --root, text, overwrite an existing file?)
    "unit": (f"etc/systemd/system/{UNIT_NAME}", unit_text, True),
    "config": ("etc/adxl-gateway/gateway.toml", default_config_text, False),  # never a user's edits
    "dbc": ("usr/share/adxl-gateway/adxl-gateway.dbc", lambda: packaged_text("adxl-gateway.dbc"), True),
    "doc": ("usr/share/doc/adxl-gateway/daemon.md", lambda: packaged_text("daemon.md"), True),
}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "install-files",
        help="print or install the systemd unit, the default config, the DBC and the daemon docs",
        description="Write the files a deployment needs under --root (default /): "
                    + "; ".join(f"{name}: {path}" for name, (path, _, _) in FILES.items())
                    + ". The unit's ExecStart names this installation's adxlgw. An existing config "
                      "is kept. Then: systemctl daemon-reload, set serial.port, systemctl enable --now "
                      "adxl-gateway.",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--root", default="/", help="install under this directory (default: /)")
    g.add_argument("--print", choices=FILES, dest="print_name", help="print one file to stdout instead")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.print_name:
        sys.stdout.write(FILES[args.print_name][1]())
        return 0
    root = Path(args.root)
    if root.exists() and not root.is_dir():
        raise InputError(f"--root {root}: not a directory")
    for relative, text, overwrite in FILES.values():
        target = root / relative
        if target.exists() and not overwrite:
            print(f"kept {target} (exists)")
            continue
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text(), encoding="utf-8")
        except OSError as err:
            raise InputError(f"cannot write {target}: {err.strerror or err}") from err
        print(f"wrote {target}")
    return 0
