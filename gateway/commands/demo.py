"""adxlgw demo: the gateway on its built-in emulated board, with a live terminal view."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

from gateway.commands.run import add_run_options, load_with_overrides, overrides_from, serve


def default_state_path() -> str:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return str(Path(base) / "adxl-gateway" / "demo-state.json")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the gateway on the built-in emulated board (Modbus on 127.0.0.1, CAN on a virtual bus)",
        description="Start the emulated board (adxlgw emulate on a pty, the paper's strokes, looping), the "
                    "gateway reading it, Modbus TCP on 127.0.0.1:5020 and CAN on a python-can virtual bus, "
                    "with a live terminal view. Any Modbus client can poll it, e.g. "
                    "mbpoll -m tcp -p 5020 -0 -B -t 3:float -r 4 -c 3 127.0.0.1",
    )
    add_run_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    overrides = {"serial.port": "emulated", "service.view": True, "state.path": default_state_path(),
                 **overrides_from(args)}
    cfg = load_with_overrides(args.config, overrides)
    print(f"adxl-gateway demo: Modbus TCP on {cfg.modbus.host}:{cfg.modbus.port}, "
          f"CAN {cfg.can.interface}:{cfg.can.channel}; Ctrl-C stops", flush=True)
    print(f"  poll it: mbpoll -m tcp -p {cfg.modbus.port} -0 -B -t 3:float -r 4 -c 3 {cfg.modbus.host}"
          f"   (position m, velocity m/s, acceleration m/s²; adxlgw regmap lists every register)", flush=True)
    reload = lambda: load_with_overrides(args.config, overrides)  # noqa: E731
    return serve(cfg, reload)
