"""The initial rest found on data the project did not make, by this checkout and another.

    .venv/bin/python -m benchmarks.tools.initial_rest_check [--compare DIR] [--seeds 5]

`reference_point.find_initial_rest` sets everything `adxlgw estimate` and `diagnose`
take from a recording's own rest (the offset, the noise settings, the paper method's
reference point). This prints, per recording, the rest it finds — first and end sample,
offset, σ — and the data's step (the smallest difference between two of its values),
on: the two Leiria robot files (imported on the sensor clock, as estimation_benchmark
reads them), the six airbrakes files (z axis, as estimation_benchmark imports them), and
the independent generator's recordings (tests/independent_generator: every effect and
the clean case, seeds 0…N−1). With `--compare DIR` the same with DIR's
`gateway/core/reference_point.py` (a checkout of another commit, e.g. `git worktree add
/tmp/old <sha>`): identical rests mean identical settings and estimates downstream.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib.util
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.harness import machine
from gateway.cli import main as adxlgw
from gateway.core import reference_point
from gateway.offline.recording import read_recording, to_acceleration
from testing.diagnosis_cases import EFFECTS
from testing.independent_generator.cases import make_case

ROOT = Path(__file__).resolve().parents[2]

ROBOT = ROOT / "datasets" / "leiria-robot"
AIRBRAKES = ROOT / "datasets" / "airbrakes-imu"


def imported(source: Path, argv: list[str]):
    with tempfile.TemporaryDirectory() as tmp, open(os.devnull, "w") as null, contextlib.redirect_stderr(null):
        path = os.path.join(tmp, "imported.csv")
        if adxlgw(["import", str(source), *argv, "--out", path]) != 0:
            raise SystemExit(f"adxlgw import {source} failed")
        series = to_acceleration(read_recording(path))
    return series.acc_mps2, series.valid, float(np.median(np.diff(series.t_s)))


def recordings(seeds: int):
    for name in ("eV50p_MPU6050RM3100.csv", "V1000_LSM9DS0.csv"):
        yield f"robot {name}", imported(ROBOT / name, ["--time-col", "sensor_time_s", "--acc-col", "acc_z_g",
                                                       "--acc-unit", "g"])
    for name in ("xplus", "xminus", "yplus", "yminus", "zplus", "zminus"):
        yield f"airbrakes {name}", imported(AIRBRAKES / f"{name}.csv", [
            "--time-col", "timestamp", "--time-unit", "ns", "--acc-col", "scaledAccelZ", "--acc-unit", "g"])
    for effect in (None, *EFFECTS):
        for seed in range(seeds):
            data = make_case(effect, seed).data
            yield (f"independent {effect or 'clean'} {seed}",
                   (data.acc_mps2, data.valid, float(np.median(np.diff(data.t_s)))))


def rest_of(module, acc, valid, period) -> str:
    try:
        r = module.find_initial_rest(acc, valid, period)
    except module.NoRestError as err:
        return f"no rest: {err}"
    return f"{r.start}–{r.stop} offset {r.offset_mps2:+.6f} σ {r.sample_std_mps2:.6f}"


def load_module(checkout: Path):
    spec = importlib.util.spec_from_file_location("other_reference_point",
                                                  checkout / "gateway" / "core" / "reference_point.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (its dataclasses look their module up there)
    spec.loader.exec_module(module)
    return module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", type=Path, help="another checkout whose rest search to run beside this one")
    ap.add_argument("--seeds", type=int, default=5, help="independent-generator seeds per effect")
    args = ap.parse_args()
    other = load_module(args.compare) if args.compare else None
    print(f"command: .venv/bin/python -m benchmarks.tools.initial_rest_check --seeds {args.seeds}"
          + (f" --compare {args.compare}" if args.compare else ""))
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    print("| recording | samples | data step (m/s²) | rest, this checkout | " + ("other checkout |" if other else ""))
    print("| --- | --- | --- | --- |" + (" --- |" if other else ""))
    same = total = 0
    for name, (acc, valid, period) in recordings(args.seeds):
        ok = np.asarray(valid, bool) & np.isfinite(acc)
        step = float(np.diff(np.unique(acc[ok][:200_000])).min())
        here = rest_of(reference_point, acc, valid, period)
        row = f"| {name} | {acc.size} | {step:.3g} | {here} |"
        if other is not None:
            there = rest_of(other, acc, valid, period)
            same += here == there
            row += " same |" if here == there else f" {there} |"
        total += 1
        print(row)
    if other is not None:
        print(f"identical rest on {same} of {total} recordings")


if __name__ == "__main__":
    main()
