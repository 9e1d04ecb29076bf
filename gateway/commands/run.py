"""adxlgw run: the gateway daemon (board → estimator → Modbus and CAN)."""
from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import sys
from typing import NoReturn

from gateway.config import Config, load_config
from gateway.daemon.preflight import refuse_unrunnable

log = logging.getLogger("adxlgw")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="run the gateway daemon",
        description="Read the board, estimate distance and velocity, serve them over Modbus TCP (and RTU) "
                    "and CAN. SIGTERM stops, SIGHUP reloads the config. Under systemd: Type=notify.",
    )
    add_run_options(p)
    p.set_defaults(run=run)


def add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="TOML config (adxlgw config --default prints one)")
    p.add_argument("--serial", metavar="PORT", help="override serial.port (a device, a pyserial URL, or 'emulated')")
    p.add_argument("--modbus-host", help="override modbus.host")
    p.add_argument("--modbus-port", type=int, help="override modbus.port")
    p.add_argument("--can-interface", help="override can.interface (socketcan, virtual, …)")
    p.add_argument("--can-channel", help="override can.channel (vcan0, can0, …)")
    p.add_argument("--view", action="store_true", help="draw a live terminal view")


def overrides_from(args: argparse.Namespace) -> dict:
    pairs = {
        "serial.port": args.serial,
        "modbus.host": args.modbus_host,
        "modbus.port": args.modbus_port,
        "can.interface": args.can_interface,
        "can.channel": args.can_channel,
        "service.view": True if args.view else None,
    }
    return {k: v for k, v in pairs.items() if v is not None}


def load_overridden(path: str | None, overrides: dict) -> Config:
    """The config file with the command line's overrides (a reload reads it again; the
    daemon checks it against the running one: preflight.refuse_reload)."""
    cfg = load_config(path)
    return cfg.replace(overrides) if overrides else cfg


def load_with_overrides(path: str | None, overrides: dict) -> Config:
    """The config `run` starts with; ConfigError (exit 2) or DeviceError (exit 3) if it
    cannot run (the checks of `config --check`: preflight.findings)."""
    cfg = load_overridden(path, overrides)
    for finding in refuse_unrunnable(cfg):
        log.log(logging.WARNING if finding.severity == "device" else logging.INFO, "%s", finding.line(cfg.source))
    return cfg


def serve(cfg: Config, reload) -> int:
    from gateway.daemon import Gateway  # the daemon pulls in pymodbus and python-can

    logging.getLogger().setLevel(cfg.service.log_level.upper())
    if not cfg.service.view:
        return asyncio.run(Gateway(cfg, reload=reload).run())
    from gateway.daemon.terminal_view import TerminalView  # rich: the [offline] extra (preflight checks)

    with TerminalView() as view:  # log lines above, the view below, until the daemon ends
        return asyncio.run(Gateway(cfg, reload=reload, view=view).run())


def run(args: argparse.Namespace) -> NoReturn:
    overrides = overrides_from(args)
    cfg = load_with_overrides(args.config, overrides)
    reload = (lambda: load_overridden(args.config, overrides)) if args.config else None
    exit_now(serve(cfg, reload))


def exit_now(code: int) -> NoReturn:
    """End the process without the interpreter's teardown. The gateway has stopped by
    now: ports and servers closed, state saved, "stopped" logged. What the teardown would
    still do is collect and free every object of numpy, scipy, numba and pymodbus: 0.4-0.6 s
    of a 0.6 s stop on this machine's CPU (SIGTERM to exit, measured in docs/daemon.md),
    against the unit's TimeoutStopSec=2s, and ~10x that on a slow CPU. Only the log is
    left to flush; nothing of ours is registered with atexit."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed or broken stream: nothing more can be said on it
            stream.flush()
    os._exit(code)
