"""adxlgw demo: the gateway on its built-in emulated board, with a live terminal view."""
from __future__ import annotations

import argparse
from pathlib import Path

from gateway.commands.run import add_run_options, load_overridden, load_with_overrides, overrides_from, serve
from gateway.owned_tempdir import OwnedTempDir

# the demo chooses the emulated board and an in-process CAN bus on purpose; nothing of a
# demo run survives it (its state lives in a temporary directory), so each run starts
# where a fresh gateway would
DEMO_SETTINGS = {"serial.port": "emulated", "estimator.start_at_rest": True, "can.interface": "virtual",
                 "can.channel": "adxlgw-demo", "service.view": True}
DEMO_DIR_PREFIX = "adxlgw-demo-"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo",
        help="run the gateway on the built-in emulated board (Modbus on 127.0.0.1, CAN on a virtual bus)",
        description="Start the emulated board (adxlgw emulate on a pty, the paper's strokes, looping), the "
                    "gateway reading it, Modbus TCP on 127.0.0.1:5020 and CAN on a python-can virtual bus, "
                    "with a live terminal view. Every value is simulated, and nothing is kept between "
                    "runs. Any Modbus client can poll it, e.g. "
                    "mbpoll -m tcp -p 5020 -0 -B -t 3:float -r 4 -c 3 127.0.0.1",
    )
    add_run_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    with OwnedTempDir(DEMO_DIR_PREFIX) as state_dir:
        overrides = {**DEMO_SETTINGS, "state.path": str(Path(state_dir) / "state.json"), **overrides_from(args)}
        cfg = load_with_overrides(args.config, overrides)
        print(f"adxl-gateway demo (simulated board): Modbus TCP on {cfg.modbus.host}:{cfg.modbus.port}, "
              f"CAN {cfg.can.interface}:{cfg.can.channel}; Ctrl-C stops", flush=True)
        print(f"  poll it: mbpoll -m tcp -p {cfg.modbus.port} -0 -B -t 3:float -r 4 -c 3 {cfg.modbus.host}"
              f"   (position m, velocity m/s, acceleration m/s²; adxlgw regmap lists every register)", flush=True)
        reload = lambda: load_overridden(args.config, overrides)  # noqa: E731
        return serve(cfg, reload)
