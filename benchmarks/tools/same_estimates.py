"""Are the estimates of this checkout bit-identical to another's? For a refactor of the
estimator (its kernel split into phases, its records), the answer must be yes.

    .venv/bin/python -m benchmarks.tools.compare same-estimates --compare DIR [--json PATH]

DIR is another checkout, e.g. a worktree of main (`git worktree add /work/w_main main`);
each checkout runs its own code with this interpreter (PYTHONPATH = the checkout). Every
column of every estimate is compared byte for byte (NaN included), on:
1. the six Leiria robot files, imported as `adxlgw import` reads them (sensor clock, and the
   logger's arrival clock — with `--nominal-rate-hz` where the importer asks for it),
   settings from the initial rest; realtime and smoothed, without and with the robot's hint;
2. the airbrakes recordings zplus/zminus, realtime and smoothed;
3. the simulator: the robot-like path (100 and 500 Hz, seeds 0 and 1, with and without the
   resting hint) and the paper's 10 strokes (seed 0), realtime and smoothed;
4. the daemon's way: `RealtimeEstimator.step` sample by sample (with `set_hint` where there is
   a hint) on the robot-like path and one robot file — every field of every `Estimate`.
The estimate's notes are text and listed where they differ (a new note is not a new number).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

# run inside each checkout (its own gateway and testing packages): only APIs both have
WORKER = r'''
import contextlib, dataclasses, io, json, os, sys, tempfile
import numpy as np
from gateway.cli import main as adxlgw
from gateway.commands.estimate import settings_for
from gateway.core.estimator import RealtimeEstimator, estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.sensor_model import SensorParams
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import simulate
from gateway.offline.recording import read_recording, to_acceleration
from testing.robot_like_cases import robot_case
data, out_path = sys.argv[1], sys.argv[2]
arrays, notes = {}, {}

def imported(argv):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "imported.csv")
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            code = adxlgw(["import", *argv, "--out", path])
        return to_acceleration(read_recording(path)) if code == 0 else None

def offline(label, t, z, valid, settings, hint, lost=None):
    for method in ("realtime", "smoothed"):
        for hinted in ((False, True) if hint is not None else (False,)):
            key = f"{label} {method}{' + hint' if hinted else ''}"
            try:
                tr = estimate_series(t, z, valid, method=method, settings=settings, lost_before=lost,
                                     standstill_hint=hint.astype(float) if hinted else None)
            except Exception as exc:
                notes[key] = [f"raised {type(exc).__name__}: {exc}"]
                continue
            for col, values in tr.columns().items():
                arrays[f"{key}|{col}"] = np.asarray(values)
            notes[key] = list(tr.notes)

def streamed(label, t, z, settings, hint):
    est = RealtimeEstimator(settings)
    rows = []
    for k in range(t.size):
        if hint is not None:
            est.set_hint(float(hint[k]))
        e = est.step(float(t[k]), float(z[k]) if np.isfinite(z[k]) else None)
        rows.append(dataclasses.astuple(e))
    table = np.array(rows, dtype=float)
    for i, f in enumerate(dataclasses.fields(type(e))):
        arrays[f"{label} RealtimeEstimator.step|{f.name}"] = table[:, i]

FILES = {"eV50p_MPU6050RM3100": ("acc_z_g", "ref_z_m"), "V1000_LSM9DS0": ("acc_z_g", "ref_z_m"),
         "eV50p_MPU6050RM3100_y605": ("acc_along_g", "ref_m"), "eV50p_LSM9DS0_y605": ("acc_along_g", "ref_m"),
         "eV50p_SENTRAL_y605": ("acc_along_g", "ref_m"), "V1000_LSM9DS0_y605": ("acc_along_g", "ref_m")}
RATE = {"MPU6050RM3100": 1 / 0.0115, "LSM9DS0": 100.0, "SENTRAL": 100.0}
for name, (acc_col, ref_col) in FILES.items():
    src = os.path.join(data, "leiria-robot", name + ".csv")
    for clock, when in (("sensor", ["--time-col", "sensor_time_s"]), ("arrival", ["--arrival-col", "arrival_time_s"])):
        argv = [src, *when, "--acc-col", acc_col, "--acc-unit", "g", "--hint-col", "robot_at_rest"]
        s = imported(argv)
        if s is None and clock == "arrival":
            s = imported(argv + ["--nominal-rate-hz", f"{RATE[name.split('_')[1]]:g}"])
        if s is None:
            notes[f"{name}@{clock}"] = ["import refused"]
            continue
        settings = settings_for(s, "acceleration", "auto", None)
        hint = s.standstill_hint
        offline(f"{name}@{clock}", s.t_s, s.acc_mps2, s.valid, settings, hint)
        if name == "eV50p_MPU6050RM3100" and clock == "sensor":
            streamed(f"{name}@{clock}", s.t_s, np.where(s.valid, s.acc_mps2, np.nan), settings, hint)
for name in ("zplus", "zminus"):
    s = imported([os.path.join(data, "airbrakes-imu", name + ".csv"), "--time-col", "timestamp", "--time-unit", "ns",
                  "--acc-col", "scaledAccelZ", "--acc-unit", "g"])
    offline(f"airbrakes {name}", s.t_s, s.acc_mps2, s.valid, settings_for(s, "acceleration", "auto", None), None)
for rate in (100.0, 500.0):
    for seed in (0, 1):
        t, z, _ref, resting, settings = robot_case(seed, 0.0, rate_hz=rate)
        offline(f"sim robot-like {rate:g} Hz seed {seed}", t, z, np.isfinite(z), settings, resting)
        if seed == 0:
            streamed(f"sim robot-like {rate:g} Hz seed {seed}", t, z, settings, resting)
run = simulate(build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=10))), SensorParams(), seed=0)
t = sample_times_s(run.t2, run.tick_hz)
z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
offline("sim paper seed 0", t, z, np.ones(t.size, bool), from_sensor_model(SensorParams()), None)
np.savez(out_path, **arrays)
with open(out_path + ".notes.json", "w") as f:
    json.dump(notes, f)
'''


def estimates(checkout: Path, out: Path) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """Every estimate the worker makes, by `checkout`'s own code."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    subprocess.run([sys.executable, "-c", WORKER, str(ROOT / "datasets"), str(out)], cwd=checkout, env=env,
                   check=True)
    with np.load(out) as arrays:
        found = {key: arrays[key] for key in arrays.files}
    return found, json.loads(Path(str(out) + ".notes.json").read_text())


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def compare_same_estimates(checkouts: list[Path]) -> dict:
    """The first checkout's estimates against each other's, byte for byte; printed as a table."""
    found = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, checkout in enumerate(checkouts):
            found[checkout] = estimates(checkout, Path(tmp) / f"{i}.npz")
    ours, our_notes = found[checkouts[0]]
    results = {}
    for other in checkouts[1:]:
        theirs, their_notes = found[other]
        results[str(other)] = bit_identity_table(ours, theirs, our_notes, their_notes, other)
    return results


def bit_identity_table(ours, theirs, our_notes, their_notes, other: Path) -> dict:
    cases = sorted({key.split("|")[0] for key in ours} | {key.split("|")[0] for key in theirs})
    print(f"\n| estimate | columns | bit-identical to {other} |")
    print("| --- | --- | --- |")
    rows, differing = [], 0
    for case in cases:
        cols = sorted({k for k in ours if k.startswith(case + "|")} | {k for k in theirs if k.startswith(case + "|")})
        bad = [k.split("|")[1] for k in cols if k not in ours or k not in theirs or not same_bits(ours[k], theirs[k])]
        differing += bool(bad)
        print(f"| {case} | {len(cols)} | {'yes' if not bad else 'NO: ' + ', '.join(bad)} |")
        rows.append({"estimate": case, "columns": len(cols), "differing": bad})
    print(f"\n{len(cases) - differing} of {len(cases)} estimates bit-identical")
    # notes are text: each note found on one side only, with how many estimates carry it
    for side, mine, theirs_ in (("here", our_notes, their_notes), ("there", their_notes, our_notes)):
        only: dict[str, int] = {}
        for key, lines in mine.items():
            for line in lines:
                if line not in theirs_.get(key, []):
                    only[line] = only.get(line, 0) + 1
        for line, count in sorted(only.items()):
            print(f"note only {side} ({count} estimates): {line}")
    return {"rows": rows, "differing": differing}
