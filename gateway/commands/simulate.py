"""adxlgw simulate: a simulated run of the paper's experiment, written as a raw recording."""
from __future__ import annotations

import argparse
import sys

from gateway.commands.common import add_scenario_options, scenario_from_args
from gateway.core.scenarios import build_profile
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.offline.progress import progress_bar
from gateway.offline.recording import write_recording


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="write a simulated recording (raw form, with the truth)",
                       description="Simulate the board for a motion scenario and write a raw recording "
                                   "with the reference motion in ref_pos_m, ref_vel_mps, ref_acc_mps2.")
    add_scenario_options(p)
    p.add_argument("--out", required=True, help="output recording: CSV, or Parquet when it ends in .parquet")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    scenario = scenario_from_args(args)
    sensor = SensorParams()
    sim = simulate(build_profile(scenario), sensor, seed=args.seed)
    metadata = {
        "tick_hz": f"{sim.tick_hz:g}",
        "source": "simulation",
        "axis": "x",
        "scenario": scenario.name,
        "seed": str(args.seed),
    }
    if scenario.name == "paper":
        metadata["strokes"] = str(scenario.strokes.strokes)
    if scenario.name in ("paper", "move") and scenario.strokes.jerk_mps3 > 0:
        metadata["jerk_mps3"] = f"{scenario.strokes.jerk_mps3:g}"
    with progress_bar(len(sim), f"writing {args.out}", " rows") as bar:
        write_recording(args.out, metadata, sim.recording_columns(), progress=bar)
    print(f"wrote {args.out}: {len(sim)} samples, {sim.t_s[-1]:.2f} s, scenario {scenario.name}, seed {args.seed}",
          file=sys.stderr)
    return 0
