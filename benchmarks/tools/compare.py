"""The estimator on data the project did not make, this checkout beside others: a change
to the numerical core measured before against after.

    .venv/bin/python -m benchmarks.tools.compare [--compare DIR ...] [--independent-seeds 10]

Each checkout's own code (`--compare DIR`: a worktree of another commit, e.g.
`git worktree add /work/w_old ff8b6f8`) runs, with this interpreter, on:
1. the Leiria robot files on the sensor clock (eV50p: design; V1000: held out), read as
   `adxlgw import … --acc-col acc_z_g --acc-unit g`, settings from the initial rest, realtime
   and smoothed, without and with the robot's rest hint: the worst move's error (%);
2. the hand-lifted airbrakes recordings zplus/zminus (back where they began): the final
   position (= error, mm), realtime and smoothed;
3. the independent generator (tests/independent_generator, not the simulator), a clean
   recording and one per hidden effect, seeds 70000… (spent by the diagnosis benchmark,
   never used to design the estimator): the RMS of the errors at the stops (mm) and the
   share of stop ends inside ±3σ, realtime and smoothed, settings from the sensor model.
Printed per checkout, one column each.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
from pathlib import Path

from benchmarks.harness import machine

ROOT = Path(__file__).resolve().parents[2]

# run inside each checkout (its own gateway and tests packages): only APIs both have
WORKER = r'''
import contextlib, io, json, os, sys, tempfile
import numpy as np
from gateway.cli import main as adxlgw
from gateway.commands.estimate import settings_for
from gateway.core.estimator import estimate_series
from gateway.core.evaluation import move_errors, summarise_errors
from gateway.offline.recording import read_recording, to_acceleration
data, seeds = sys.argv[1], int(sys.argv[2])
out = {}

def imported(argv):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "imported.csv")
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert adxlgw(["import", *argv, "--out", path]) == 0
        return to_acceleration(read_recording(path))

for name in ("eV50p_MPU6050RM3100", "V1000_LSM9DS0"):
    src = os.path.join(data, "leiria-robot", name + ".csv")
    s = imported([src, "--time-col", "sensor_time_s", "--acc-col", "acc_z_g", "--acc-unit", "g"])
    raw = np.genfromtxt(src, delimiter=",", names=True)
    settings = settings_for(s, "acceleration", "auto", None)
    for method in ("realtime", "smoothed"):
        for hint in (False, True):
            tr = estimate_series(s.t_s, s.acc_mps2, s.valid, method=method, settings=settings,
                                 standstill_hint=raw["robot_at_rest"] if hint else None)
            moves = move_errors(tr.pos_m, raw["ref_z_m"], raw["robot_at_rest"])
            out[f"robot {name[:5]} {method}{' + hint' if hint else ''}: worst move %"] = max(m.percent for m in moves)
for name in ("zplus", "zminus"):
    s = imported([os.path.join(data, "airbrakes-imu", name + ".csv"), "--time-col", "timestamp", "--time-unit", "ns",
                  "--acc-col", "scaledAccelZ", "--acc-y-col", "scaledAccelX", "--acc-unit", "g"])
    settings = settings_for(s, "acceleration", "auto", None)
    for method in ("realtime", "smoothed"):
        tr = estimate_series(s.t_s, s.acc_mps2, s.valid, method=method, settings=settings)
        out[f"airbrakes {name} {method}: final error mm"] = float(tr.pos_m[-1]) * 1e3
try:
    from testing.independent_generator.cases import EFFECT_SIZES, make_case
except ModuleNotFoundError:  # a checkout from before the testing/ package
    from tests.independent_generator.cases import EFFECT_SIZES, make_case
for effect in [None] + [e for e in EFFECT_SIZES if e != "bias_random_walk"]:
    for method in ("realtime", "smoothed"):
        errs, inside = [], []
        for seed in range(70000, 70000 + seeds):
            case = make_case(effect, seed)
            s = to_acceleration(case.recording)
            settings = settings_for(s, "raw", "auto", None)
            try:
                tr = estimate_series(s.t_s, s.acc_mps2, s.valid, method=method, settings=settings,
                                     lost_before=s.lost_before)
            except ValueError:  # no initial rest (NoRestError): not scored
                continue
            r = s.reference
            summ = summarise_errors(s.t_s, tr.pos_m, r["ref_pos_m"], r["ref_vel_mps"], r.get("ref_acc_mps2"))
            for st in summ.stops:
                errs.append(st.error_m)
                inside.append(abs(st.error_m) <= 3 * tr.pos_std_m[st.index] + 1e-4)
        label = effect or "clean"
        out[f"independent {label} {method}: stop RMS mm"] = (
            float(np.sqrt(np.mean(np.square(errs)))) * 1e3 if errs else float("nan"))
        out[f"independent {label} {method}: stops inside 3σ %"] = (
            100.0 * float(np.mean(inside)) if inside else float("nan"))
print(json.dumps(out))
'''


def run(checkout: Path, seeds: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, "-c", WORKER, str(ROOT / "datasets"), str(seeds)], cwd=checkout, env=env,
                          check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", type=Path, action="append", default=[], help="another checkout (repeatable)")
    ap.add_argument("--independent-seeds", type=int, default=10)
    args = ap.parse_args()
    print("command: .venv/bin/python -m benchmarks.tools.compare "
          + " ".join(f"--compare {c}" for c in args.compare) + f" --independent-seeds {args.independent_seeds}")
    print(f"date: {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}; machine: {machine()}")
    checkouts = [ROOT] + args.compare
    results = [run(c, args.independent_seeds) for c in checkouts]
    names = ["this checkout"] + [str(c) for c in args.compare]
    print("| measure | " + " | ".join(names) + " |")
    print("|" + " --- |" * (len(names) + 1))
    for key in results[0]:
        print(f"| {key} | " + " | ".join(f"{r.get(key, float('nan')):.2f}" for r in results) + " |")


if __name__ == "__main__":
    main()
