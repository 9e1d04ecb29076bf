"""adxlgw demo: the main job on the built-in emulated board (interim: simulate and summarise)."""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from gateway.recording import read_recording, to_acceleration, write_recording


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="run the gateway's main job on the built-in emulated board")
    p.add_argument("--strokes", type=int, default=10)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    scenario = ScenarioSettings(strokes=StrokeSettings(strokes=args.strokes))
    sim = simulate(build_profile(scenario), seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "demo.csv"
        write_recording(path, {"tick_hz": f"{sim.tick_hz:g}", "source": "simulation", "axis": "x"},
                        sim.recording_columns())
        series = to_acceleration(read_recording(path))
    dt = np.diff(series.t_s)
    print(f"samples: {len(series)}  duration: {series.t_s[-1]:.2f} s  rate: {1 / np.median(dt):.1f} samples/s")
    print(f"acceleration: min {np.nanmin(series.acc_mps2):.2f}  max {np.nanmax(series.acc_mps2):.2f} m/s²")
    print(f"reference travel: {np.sum(np.abs(np.diff(series.reference['ref_pos_m']))):.3f} m")
    return 0
