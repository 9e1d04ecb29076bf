"""This checkout beside others: a change to the numerical core or the diagnosis measured
before against after, on data the project did not make.

    .venv/bin/python -m benchmarks.tools.compare estimation [--compare DIR ...] [--independent-seeds 10]
    .venv/bin/python -m benchmarks.tools.compare diagnosis [--compare DIR ...]
    .venv/bin/python -m benchmarks.tools.compare initial-rest [--compare DIR ...] [--seeds 5]
    .venv/bin/python -m benchmarks.tools.compare same-estimates --compare DIR
    .venv/bin/python -m benchmarks.tools.compare speed --compare DIR [--hours 0.5] [--repeats 5]

`--compare DIR` (repeatable) is another checkout, e.g. a worktree of another commit
(`git worktree add /work/w_old ff8b6f8`); each checkout runs its own code with this
interpreter, one column (or line) each.

estimation — on:
1. the Leiria robot files on the sensor clock (eV50p: design; V1000: held out), read as
   `adxlgw import … --acc-col acc_z_g --acc-unit g`, settings from the initial rest, realtime
   and smoothed, without and with the robot's rest hint: the worst move's error (%);
2. the hand-lifted airbrakes recordings zplus/zminus (back where they began): the final
   position (= error, mm), realtime and smoothed;
3. the independent generator (testing/independent_generator, not the simulator), a clean
   recording and one per hidden effect, seeds 70000… (spent by the diagnosis benchmark,
   never used to design the estimator): the RMS of the errors at the stops (mm) and the
   share of stop ends inside ±3σ, realtime and smoothed, settings from the sensor model.

same-estimates — every column of every estimate byte for byte, for a refactor of the
estimator (benchmarks/tools/same_estimates.py says on what).

speed — the estimators' CPU time per sample, each checkout in its own child on one
simulated recording, alternating (benchmarks/speed/estimator_speed.py, side_by_side).

diagnosis — the two Leiria robot files (each at the default comparison and at every
sample, as docs/diagnosis.md) and the two hand-lifted airbrakes recordings that return to
their start, each diagnosed: the effects named, the negligible ones, the not physical
ones, and whether the residual is white; for this checkout also each one's parameters
and why (`details`).

initial-rest — `reference_point.find_initial_rest` sets everything `adxlgw estimate` and
`diagnose` take from a recording's own rest (the offset, the noise settings, the paper
method's reference point). Per recording, the rest each checkout finds — first and end
sample, offset, σ — and the data's step (the smallest difference between two of its
values), on: the two Leiria robot files (imported on the sensor clock), the six airbrakes
files (z axis), and the independent generator's recordings (every effect and the clean
case, seeds 0…N−1). Identical rests mean identical settings and estimates downstream.
"""
from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import harness
from benchmarks.speed.estimator_speed import side_by_side
from benchmarks.tools.same_estimates import compare_same_estimates
from gateway.cli import main as adxlgw
from gateway.core import reference_point
from gateway.offline.recording import read_recording, to_acceleration
from testing.diagnosis_cases import EFFECTS
from testing.independent_generator.cases import make_case

ROOT = Path(__file__).resolve().parents[2]


def in_checkout(checkout: Path, argv: list[str], **kwargs) -> subprocess.CompletedProcess:
    """This interpreter run with `argv` inside `checkout`, on its own code."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    return subprocess.run([sys.executable, *argv], cwd=checkout, env=env, check=True, **kwargs)


# ------------------------------------------------------------------------------- estimation
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


def estimation_measures(checkout: Path, seeds: int) -> dict:
    done = in_checkout(checkout, ["-c", WORKER, str(ROOT / "datasets"), str(seeds)], capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])



def compare_estimation(checkouts: list[Path], seeds: int) -> dict:
    results = [estimation_measures(c, seeds) for c in checkouts]
    names = ["this checkout"] + [str(c) for c in checkouts[1:]]
    print("| measure | " + " | ".join(names) + " |")
    print("|" + " --- |" * (len(names) + 1))
    for key in results[0]:
        print(f"| {key} | " + " | ".join(f"{r.get(key, float('nan')):.2f}" for r in results) + " |")
    return {str(c): r for c, r in zip(checkouts, results, strict=True)}


# -------------------------------------------------------------------------------- diagnosis
def _quiet(checkout: Path, argv: list[str]) -> None:
    in_checkout(checkout, argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


ROBOT_FILES = ("eV50p_MPU6050RM3100", "V1000_LSM9DS0")
AIRBRAKE_FILES = ("zplus", "zminus")


def _real_data_command(checkout: Path) -> list[str]:
    """How `checkout` runs diagnosis_real_data: a module since benchmarks/ is a package,
    a script before."""
    if (checkout / "benchmarks" / "accuracy" / "diagnosis_real_data.py").exists():
        return ["-m", "benchmarks.accuracy.diagnosis_real_data"]
    return ["benchmarks/diagnosis_real_data.py"]


def diagnoses(checkout: Path, tmp: Path) -> dict[str, dict]:
    """{case: the diagnosis JSON} for the six cases, by this checkout's code."""
    out: dict[str, dict] = {}
    data = ROOT / "datasets"
    for name in ROBOT_FILES:
        for label, extra in (("default comparison", []), ("every sample", ["--reference-block", "1"])):
            where = tmp / f"{name}-{len(extra)}"
            _quiet(checkout, [*_real_data_command(checkout), str(data / "leiria-robot" / f"{name}.csv"),
                            "--out", str(where), *extra])
            out[f"robot {name}, {label}"] = json.loads(next(where.glob("*.diagnosis.json")).read_text())
    for name in AIRBRAKE_FILES:
        rec, result = tmp / f"{name}.csv", tmp / f"{name}.json"
        _quiet(checkout, ["-m", "gateway.cli", "import", str(data / "airbrakes-imu" / f"{name}.csv"),
                        "--time-col", "timestamp", "--time-unit", "ns", "--acc-col", "scaledAccelZ",
                        "--acc-y-col", "scaledAccelX", "--acc-unit", "g", "--out", str(rec)])
        _quiet(checkout, ["-m", "gateway.cli", "diagnose", str(rec), "--returns-to-start", "--json", str(result)])
        out[f"airbrakes {name}, returns to start"] = json.loads(result.read_text())
    return out


def summary(d: dict) -> str:
    named = ", ".join(e["name"] for e in d["effects"]) or "nothing"
    negligible = ", ".join(n["name"] for n in d.get("negligible", [])) or "–"
    not_physical = ", ".join(n["shape"] for n in d.get("not_physical", [])) or "–"
    return f"named {named}; negligible {negligible}; not physical {not_physical}; white {d['residual_white']}"


def _values(params: dict) -> str:
    """{name: [value, std or None]} (or a bare value) as `name value ± std`."""
    def one(v) -> str:
        value, std = (v[0], v[1]) if isinstance(v, list | tuple) else (v, None)
        text = f"{value:.4g}" if isinstance(value, int | float) else str(value)
        return text + (f" ± {std:.2g}" if isinstance(std, int | float) else "")
    return ", ".join(f"{k} {one(v)}" for k, v in params.items())


def details(d: dict) -> list[str]:
    """What docs/diagnosis.md §8 quotes beyond the summary: each named effect with its
    parameters, distance gain and what it cannot be told from; each accepted effect not
    named (negligible or harmful), each not physical one, and the setup's, with why; what
    is left unexplained; any failure."""
    lines = []
    for e in d["effects"]:
        dist = e["gain"].get("distance", {})
        gain = f"{dist['improvement_mm']:+.2f} mm" if dist.get("available") else "n/a"
        lines.append(f"named {e['name']}: {_values(e['params'])}; distance {gain}"
                     + (f"; not separable from {', '.join(e['not_separable_from'])}"
                        if e.get("not_separable_from") else ""))
    lines += [f"not named {n['name']}: {_values(n['params'])} — {n['why']}" for n in d.get("negligible", [])]
    lines += [f"not physical {n['shape']}: {n['why']}" for n in d.get("not_physical", [])]
    lines += [f"setup {s['name']}: {_values(s['params'])}" for s in d.get("setup", [])]
    if d.get("leftover"):
        left = d["leftover"]
        lines.append(f"left unexplained: {left['what']}, {100 * left['share']:.1f} % of the residual variance")
    lines += [f"failed: {f['what']}: {f['error']}" for f in d.get("failures", [])]
    return lines


def compare_diagnosis(checkouts: list[Path]) -> dict:
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, checkout in enumerate(checkouts):
            where = Path(tmp) / str(i)
            where.mkdir()
            results[checkout] = diagnoses(checkout, where)
    for case in results[ROOT]:
        print(case)
        for checkout in checkouts:
            label = "this checkout" if checkout == ROOT else str(checkout)
            print(f"  {label:24s} {summary(results[checkout][case])}")
        for line in details(results[ROOT][case]):
            print(f"    {line}")
        same = all(summary(results[c][case]) == summary(results[ROOT][case]) for c in checkouts)
        print(f"  {'same' if same else 'DIFFERENT'}")
    return {str(c): {case: summary(d) for case, d in results[c].items()} for c in checkouts}


# ----------------------------------------------------------------------------- initial rest
ROBOT_DIR = ROOT / "datasets" / "leiria-robot"
AIRBRAKES_DIR = ROOT / "datasets" / "airbrakes-imu"


def _imported(source: Path, argv: list[str]):
    with tempfile.TemporaryDirectory() as tmp, open(os.devnull, "w") as null, contextlib.redirect_stderr(null):
        path = os.path.join(tmp, "imported.csv")
        if adxlgw(["import", str(source), *argv, "--out", path]) != 0:
            raise SystemExit(f"adxlgw import {source} failed")
        series = to_acceleration(read_recording(path))
    return series.acc_mps2, series.valid, float(np.median(np.diff(series.t_s)))


def recordings(seeds: int):
    for name in ("eV50p_MPU6050RM3100.csv", "V1000_LSM9DS0.csv"):
        yield f"robot {name}", _imported(ROBOT_DIR / name, ["--time-col", "sensor_time_s", "--acc-col", "acc_z_g",
                                                       "--acc-unit", "g"])
    for name in ("xplus", "xminus", "yplus", "yminus", "zplus", "zminus"):
        yield f"airbrakes {name}", _imported(AIRBRAKES_DIR / f"{name}.csv", [
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


def reference_point_of(checkout: Path):
    spec = importlib.util.spec_from_file_location("other_reference_point",
                                                  checkout / "gateway" / "core" / "reference_point.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (its dataclasses look their module up there)
    spec.loader.exec_module(module)
    return module


def compare_initial_rest(checkouts: list[Path], seeds: int) -> dict:
    others = [reference_point_of(c) for c in checkouts[1:]]
    print("| recording | samples | data step (m/s²) | rest, this checkout | "
          + "".join(f"{c} |" for c in checkouts[1:]))
    print("| --- | --- | --- | --- |" + " --- |" * len(others))
    same = [0] * len(others)
    total = 0
    rows: dict[str, list[str]] = {}
    for name, (acc, valid, period) in recordings(seeds):
        ok = np.asarray(valid, bool) & np.isfinite(acc)
        step = float(np.diff(np.unique(acc[ok][:200_000])).min())
        here = rest_of(reference_point, acc, valid, period)
        rows[name] = [here]
        row = f"| {name} | {acc.size} | {step:.3g} | {here} |"
        for k, other in enumerate(others):
            there = rest_of(other, acc, valid, period)
            rows[name].append(there)
            same[k] += here == there
            row += " same |" if here == there else f" {there} |"
        total += 1
        print(row)
    for checkout, n in zip(checkouts[1:], same, strict=True):
        print(f"{checkout}: identical rest on {n} of {total} recordings")
    return {"checkouts": [str(c) for c in checkouts], "rests": rows}


def main() -> None:
    ap = harness.parser(__doc__)
    ap.add_argument("what", choices=("estimation", "diagnosis", "initial-rest", "same-estimates", "speed"))
    ap.add_argument("--compare", type=Path, action="append", default=[], help="another checkout (repeatable)")
    ap.add_argument("--independent-seeds", type=int, default=10, help="estimation: seeds per effect")
    ap.add_argument("--seeds", type=int, default=5, help="initial-rest: independent-generator seeds per effect")
    ap.add_argument("--hours", type=float, default=0.5, help="speed: the simulated recording's length")
    ap.add_argument("--repeats", type=int, default=5, help="speed: rounds, the checkouts alternating")
    args = ap.parse_args()
    run = harness.stamp("benchmarks.tools.compare")
    checkouts = [ROOT, *[c.resolve() for c in args.compare]]
    if args.what == "estimation":
        results = compare_estimation(checkouts, args.independent_seeds)
    elif args.what == "diagnosis":
        results = compare_diagnosis(checkouts)
    elif args.what == "same-estimates":
        results = compare_same_estimates(checkouts)
    elif args.what == "speed":
        results = side_by_side(checkouts, args.hours, args.repeats)
    else:
        results = compare_initial_rest(checkouts, args.seeds)
    harness.write_json(args, results, run)


if __name__ == "__main__":
    main()
