"""The estimator over the whole corpus: every real recording in the repo and the simulator's runs.

    nice .venv/bin/python -m benchmarks.accuracy.estimation_corpus [--seeds 3] [--json OUT.json] [--compare zupt]

One instrument for every design choice of the estimator (docs/estimation.md, "The corpus"):
judged on the median and the worst over the corpus, never on one file.

Cases
- real: the six Leiria robot files (datasets/leiria-robot: vertical moves on acc_z_g and
  the y605 horizontal move on acc_along_g), each read as a user would with `adxlgw import`
  on the sensor clock and on the logger's arrival times (`--arrival-col`: re-timed by the
  importer); the robot's "in position" is the hint and the rests' ends are where the
  moves are scored; the airbrakes recordings that end at rest (zplus, zminus: up and back,
  so the final position is the error).
- simulated: the robot-like path (benchmarks/accuracy/robot_like_sweep.py: 100 samples/s, 5 mm/s²
  noise) and the paper's strokes (`adxlgw simulate --scenario paper --strokes 10`), seeds
  0 … --seeds − 1, settings from the sensor model.
Per file and case: the worst move's error (% of the move), the worst position error at a
rest's end, how many rest ends lie inside ±3σ, the share of the time flagged not
trustworthy (flag 256), and the confidently wrong rest ends (more than 3σ off without the
flag). Then the median and the worst of each row over the corpus.

--compare METHOD adds a method judged beside the shipped ones (estimator.COMPARED_METHODS:
zupt, the offline ZUPT smoother of gateway/core/zupt_smoother.py), with and without the
hint, on the same cases and perturbations.

Perturbations (the evidence that nothing is tuned): the hint moved by ±50 and ±100 ms
(robot files, sensor clock); the simulator's noise doubled; its rate 87, 100, 500 Hz.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import multiprocessing
import os
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from benchmarks.harness import machine
from gateway.core.estimator import COMPARED_METHODS

REPO = Path(__file__).resolve().parents[2]

ROBOT = REPO / "datasets" / "leiria-robot"
AIRBRAKES = REPO / "datasets" / "airbrakes-imu"
# file → (acceleration column, reference column); the y605 files' axis along the move
ROBOT_FILES = {
    "eV50p_MPU6050RM3100.csv": ("acc_z_g", "ref_z_m"),
    "V1000_LSM9DS0.csv": ("acc_z_g", "ref_z_m"),
    "eV50p_MPU6050RM3100_y605.csv": ("acc_along_g", "ref_m"),
    "eV50p_LSM9DS0_y605.csv": ("acc_along_g", "ref_m"),
    "eV50p_SENTRAL_y605.csv": ("acc_along_g", "ref_m"),
    "V1000_LSM9DS0_y605.csv": ("acc_along_g", "ref_m"),
}
# the sensor's configured rate, as the dataset's README gives its period (for `--nominal-rate-hz`)
NOMINAL_RATE_HZ = {"MPU6050RM3100": 1 / 0.0115, "LSM9DS0": 100.0, "SENTRAL": 100.0}
AIRBRAKES_FILES = ("zplus.csv", "zminus.csv")
# (method, hint)
RUNS = (("realtime", False), ("realtime", True), ("smoothed", False), ("smoothed", True))
HINT_SHIFTS_S = (-0.1, -0.05, 0.05, 0.1)
SIM_RATES_HZ = (87.0, 100.0, 500.0)
SIM_NOISE_MPS2 = 0.005  # the robot-like path's per-sample noise (robot_like_sweep's middle)


@dataclass
class Case:
    """One recording, ready for the estimator: what to score it against."""

    name: str
    kind: str  # robot / airbrakes / sim-robot / sim-paper
    t_s: np.ndarray
    acc_mps2: np.ndarray
    valid: np.ndarray
    ref_m: np.ndarray | None  # None: only the final position is known (0: ends where it began)
    rest: np.ndarray  # the truth's (or the machine's) rests, bool per sample
    settings: object = None
    lost_before: np.ndarray | None = None
    error: str | None = None
    extra: dict = field(default_factory=dict)


def quiet_adxlgw(argv: list[str]) -> int:
    from gateway.cli import main as adxlgw

    with open(os.devnull, "w") as null, contextlib.redirect_stderr(null), contextlib.redirect_stdout(null):
        return adxlgw(argv)


def imported(argv: list[str]):
    """`adxlgw import …` into a temporary file, read back as `adxlgw estimate` reads it."""
    from gateway.offline.recording import read_recording, to_acceleration

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "rec.csv")
        code = quiet_adxlgw(["import", *argv, "--out", path])
        if code != 0:
            return None, f"adxlgw import exited {code}"
        return to_acceleration(read_recording(path)), None


def settings_of(series):
    from gateway.commands.estimate import settings_for

    return settings_for(series, "acceleration", "auto", None)


def robot_case(name: str, clock: str) -> Case:
    acc_col, ref_col = ROBOT_FILES[name]
    when = ["--time-col", "sensor_time_s"] if clock == "sensor" else ["--arrival-col", "arrival_time_s"]
    argv = [str(ROBOT / name), *when, "--acc-col", acc_col, "--acc-unit", "g", "--ref-pos-col", ref_col,
            "--hint-col", "robot_at_rest"]
    series, err = imported(argv)
    label = f"{name.removesuffix('.csv')}@{clock}"
    if series is None and clock == "arrival":
        # the importer refuses a file whose start-up backlog is most of it unless told the
        # sensor's configured rate — which a user knows (the dataset's README gives it)
        rate_hz = NOMINAL_RATE_HZ[name.removesuffix('.csv').split('_')[1]]
        series, err = imported(argv + ["--nominal-rate-hz", f"{rate_hz:g}"])
        label += " (--nominal-rate-hz)"
    if series is None:
        return Case(label, "robot", *(np.zeros(0),) * 3, None, np.zeros(0, bool), error=err)
    case = Case(label, "robot", series.t_s, series.acc_mps2, series.valid, series.reference["ref_pos_m"],
                series.standstill_hint > 0.5)
    try:
        case.settings = settings_of(series)
    except Exception as exc:  # noqa: BLE001 — reported as the command would
        case.error = f"{type(exc).__name__}: {exc}"
    return case


def airbrakes_case(name: str) -> Case:
    series, err = imported([str(AIRBRAKES / name), "--time-col", "timestamp", "--time-unit", "ns",
                            "--acc-col", "scaledAccelZ", "--acc-unit", "g"])
    label = f"airbrakes {name.removesuffix('.csv')}"
    if series is None:
        return Case(label, "airbrakes", *(np.zeros(0),) * 3, None, np.zeros(0, bool), error=err)
    rest = np.zeros(series.t_s.size, dtype=bool)
    case = Case(label, "airbrakes", series.t_s, series.acc_mps2, series.valid, None, rest)
    try:
        case.settings = settings_of(series)
    except Exception as exc:  # noqa: BLE001
        case.error = f"{type(exc).__name__}: {exc}"
    return case


def sim_robot_case(seed: int, rate_hz: float = 100.0, noise_mps2: float = SIM_NOISE_MPS2) -> Case:
    from testing.robot_like_cases import robot_case as build

    t, z, ref, resting, settings = build(seed, 0.0, rate_hz=rate_hz, noise_mps2=noise_mps2)
    return Case(f"sim robot-like {rate_hz:g} Hz noise {noise_mps2 * 1e3:g} mm/s² seed {seed}", "sim-robot", t, z,
                np.isfinite(z), ref, resting, settings)


def sim_paper_case(seed: int) -> Case:
    from gateway.core.estimator_settings import from_sensor_model
    from gateway.core.sensor_model import SensorParams
    from gateway.offline.recording import read_recording, to_acceleration

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "paper.csv")
        assert quiet_adxlgw(["simulate", "--scenario", "paper", "--strokes", "10", "--seed", str(seed),
                             "--out", path]) == 0
        series = to_acceleration(read_recording(path))
    ref = series.reference
    resting = (np.abs(ref["ref_vel_mps"]) < 1e-12) & (np.abs(ref["ref_acc_mps2"]) < 1e-9)
    return Case(f"sim paper seed {seed}", "sim-paper", series.t_s, series.acc_mps2, series.valid,
                ref["ref_pos_m"], resting, from_sensor_model(SensorParams()), lost_before=series.lost_before)


def shifted(rest: np.ndarray, t_s: np.ndarray, shift_s: float) -> np.ndarray:
    """The hint as a machine whose word comes shift_s later (> 0) or earlier than the truth's."""
    idx = np.searchsorted(t_s, t_s - shift_s, side="right") - 1
    out = rest[np.clip(idx, 0, rest.size - 1)]
    out[idx < 0] = rest[0]
    return out


ALIGN_HINT = os.environ.get("ADXLGW_CORPUS_ALIGN_HINT") == "1"  # --align-hint (set before the workers spawn)


def numeric_settings() -> list[str]:
    """The EstimatorSettings fields a number replaces (--set, settings_lofo --setting)."""
    from dataclasses import fields

    from gateway.core.estimator_settings import EstimatorSettings

    return sorted(f.name for f in fields(EstimatorSettings) if f.type in ("float", "int"))


def settings_overrides(text: str) -> dict[str, float]:
    """--set NAME=VALUE,…: EstimatorSettings fields (numbers) replaced on every case's own
    settings — to judge a setting on the whole corpus, side by side with the shipped one."""
    numeric = numeric_settings()
    out = {}
    for item in filter(None, text.split(",")):
        name, _, value = item.partition("=")
        if name not in numeric:
            raise ValueError(f"--set {item}: not a numeric EstimatorSettings field ({', '.join(numeric)})")
        try:
            out[name] = float(value)
        except ValueError:
            raise ValueError(f"--set {item}: {value!r} is not a number") from None
    return out


SETTINGS_OVERRIDES = settings_overrides(os.environ.get("ADXLGW_CORPUS_SET", ""))  # --set (as --align-hint)


def score(case: Case, method: str, hint: np.ndarray | None, overrides: dict | None = None) -> dict:
    """One estimate of one case, scored; the case's settings with `overrides` replaced
    (by default --set's)."""
    from gateway.core.estimator import estimate_series
    from gateway.core.evaluation import move_errors

    settings = case.settings
    overrides = SETTINGS_OVERRIDES if overrides is None else overrides
    if overrides and settings is not None:
        settings = replace(settings, **overrides)
    try:
        track = estimate_series(case.t_s, case.acc_mps2, case.valid, method=method, settings=settings,
                                lost_before=case.lost_before,
                                standstill_hint=None if hint is None else hint.astype(float),
                                align_hint=ALIGN_HINT)
    except Exception as exc:  # noqa: BLE001 — a refusal is a result too
        return {"error": f"{type(exc).__name__}: {str(exc)[:80]}"}
    flagged = 100.0 * float(track.untrusted.mean())
    if case.ref_m is None:  # ends where it began: the final position is the error
        ends = np.array([track.t_s.size - 1])
        err = np.abs(track.pos_m[ends])
        worst_move = None
    else:
        moves = move_errors(track.pos_m, case.ref_m, case.rest)
        ends = np.array([m.end for m in moves], dtype=int)
        err = np.abs(track.pos_m[ends] - case.ref_m[ends])
        worst_move = max((m.percent for m in moves), default=None)
    sigma3 = 3.0 * track.pos_std_m[ends]
    inside = err <= sigma3
    wrong = (~inside) & ~track.untrusted[ends]
    return {"worst_move_pct": worst_move, "worst_rest_mm": float(err.max()) * 1e3 if err.size else None,
            "inside": int(inside.sum()), "rests": int(ends.size), "flagged_pct": flagged,
            "confidently_wrong": int(wrong.sum()),
            "median_3sigma_mm": float(np.median(sigma3)) * 1e3 if sigma3.size else None}


def build_cases(seeds: int) -> list[Case]:
    cases = [robot_case(n, c) for c in ("sensor", "arrival") for n in ROBOT_FILES]
    cases += [airbrakes_case(n) for n in AIRBRAKES_FILES]
    cases += [sim_robot_case(s) for s in range(seeds)]
    cases += [sim_paper_case(s) for s in range(seeds)]
    return cases


def runs_with(compare: tuple[str, ...]) -> tuple[tuple[str, bool], ...]:
    return RUNS + tuple((m, h) for m in compare for h in (False, True))


def run_case(job: tuple) -> dict:
    case, compare = job
    rows = {}
    if case.error:
        return {"name": case.name, "kind": case.kind, "error": case.error, "rows": rows}
    for method, use_hint in runs_with(compare):
        if use_hint and case.kind == "airbrakes":
            continue  # no machine: no hint
        rows[f"{method}{' hint' if use_hint else ''}"] = score(case, method, case.rest if use_hint else None)
    return {"name": case.name, "kind": case.kind, "rows": rows}


def run_perturbation(job: tuple) -> dict:
    what, arg, compare = job
    if what == "hint":
        name, shift = arg
        case = robot_case(name, "sensor")
        if case.error:
            return {"what": f"hint {shift * 1e3:+.0f} ms", "name": case.name, "error": case.error}
        hint = shifted(case.rest, case.t_s, shift)
        return {"what": f"hint {shift * 1e3:+.0f} ms", "name": case.name,
                "rows": {f"{m} hint": score(case, m, hint) for m in ("realtime", "smoothed", *compare)}}
    seed, rate, noise = arg
    case = sim_robot_case(seed, rate, noise)
    runs = {"realtime": RUNS[0], "realtime hint": RUNS[1], "smoothed": RUNS[2]}
    runs.update({m: (m, False) for m in compare})
    return {"what": f"sim {rate:g} Hz noise ×{noise / SIM_NOISE_MPS2:g}", "name": case.name,
            "rows": {k: score(case, m, case.rest if h else None) for k, (m, h) in runs.items()}}


def fmt(v, spec: str, unit: str = "") -> str:
    return "—" if v is None else f"{v:{spec}}{unit}"


def row_text(name: str, label: str, r: dict) -> str:
    if "error" in r:
        return f"| {name} | {label} | refused: {r['error']} | | | | |"
    return (f"| {name} | {label} | {fmt(r['worst_move_pct'], '.1f', ' %')} | {fmt(r['worst_rest_mm'], '.0f', ' mm')} "
            f"| {r['inside']}/{r['rests']} | {r['flagged_pct']:.0f} % | {r['confidently_wrong']} |")


def summary(results: list[dict], kinds: tuple[str, ...], clock: str | None = None) -> list[str]:
    lines = []
    labels = sorted({k for res in results for k in res.get("rows", {})})
    for label in labels:
        vals, rest_mm, wrong, refused, inside, rests = [], [], 0, 0, 0, 0
        for res in results:
            if res["kind"] not in kinds or (clock and f"@{clock}" not in res["name"]):
                continue
            r = res.get("rows", {}).get(label)
            if r is None:
                if "error" in res:
                    refused += 1
                continue
            if "error" in r:
                refused += 1
                continue
            wrong += r["confidently_wrong"]
            inside += r["inside"]
            rests += r["rests"]
            if r["worst_rest_mm"] is not None:
                rest_mm.append(r["worst_rest_mm"])
            if r["worst_move_pct"] is not None:
                vals.append(r["worst_move_pct"])
        if not rest_mm and not refused:
            continue
        med = f"{np.median(vals):.1f} %" if vals else "—"
        worst = f"{np.max(vals):.1f} %" if vals else "—"
        rest = f"{np.median(rest_mm):.0f} / {np.max(rest_mm):.0f} mm" if rest_mm else "—"
        lines.append(f"| {'/'.join(kinds)}{'@' + clock if clock else ''} | {label} | {med} | {worst} | {rest} "
                     f"| {inside}/{rests} | {len(rest_mm)} | {refused} | {wrong} |")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="simulator seeds per simulated row (0 …)")
    parser.add_argument("--no-perturbations", action="store_true")
    parser.add_argument("--json", help="write the results here too")
    parser.add_argument("--compare", action="append", default=[], choices=COMPARED_METHODS,
                        help="a method to judge beside the shipped ones (repeatable)")
    parser.add_argument("--align-hint", action="store_true",
                        help="shift the machine's hint by its latency measured on each recording "
                             "(gateway/core/hint_latency.py) before the estimator sees it")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="replace an estimator setting (a numeric EstimatorSettings field) on every case, "
                             "e.g. --set standstill_window_s=0.05 (repeatable)")
    args = parser.parse_args()
    try:
        settings_overrides(",".join(args.set))
    except ValueError as err:
        parser.error(str(err))
    os.environ["ADXLGW_CORPUS_SET"] = ",".join(args.set)  # the pool's spawned workers read it
    if args.align_hint:
        os.environ["ADXLGW_CORPUS_ALIGN_HINT"] = "1"  # the pool's spawned workers read it
    compare = tuple(args.compare)
    print(f"command: python -m benchmarks.accuracy.estimation_corpus --seeds {args.seeds}"
          + (" --no-perturbations" if args.no_perturbations else "") + (" --align-hint" if args.align_hint else "")
          + "".join(f" --compare {m}" for m in compare) + "".join(f" --set {s}" for s in args.set))
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    cases = build_cases(args.seeds)
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        results = pool.map(run_case, [(case, compare) for case in cases], chunksize=1)
        perturbed = [] if args.no_perturbations else pool.map(run_perturbation, [
            ("hint", (n, s), compare) for n in ROBOT_FILES for s in HINT_SHIFTS_S] + [
            ("sim", (seed, rate, SIM_NOISE_MPS2), compare) for rate in SIM_RATES_HZ for seed in range(args.seeds)]
            + [("sim", (seed, 100.0, 2 * SIM_NOISE_MPS2), compare) for seed in range(args.seeds)], chunksize=1)
    print("\nPer file (worst move: % of the move; rest: the error at a rest's end; wrong: > 3σ off, not flagged):\n")
    print("| file | run | worst move | worst rest error | rests inside ±3σ | time flagged | confidently wrong |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for res in results:
        if "error" in res:
            print(f"| {res['name']} | all | refused: {res['error']} | | | | |")
        for label, r in res["rows"].items():
            print(row_text(res["name"], label, r))
    print("\nOver the corpus (worst move per file: median and worst; worst rest error per file: median / worst;"
          " rests inside ±3σ; files scored, refused; confidently wrong rests):\n")
    print("| files | run | median worst move | worst move | worst rest error | inside ±3σ | files | refused "
          "| confidently wrong |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for line in (summary(results, ("robot",), "sensor") + summary(results, ("robot",), "arrival")
                 + summary(results, ("airbrakes",)) + summary(results, ("sim-robot",))
                 + summary(results, ("sim-paper",))):
        print(line)
    if perturbed:
        print("\nPerturbations (worst move; per group: median and worst over its files):\n")
        print("| perturbation | run | median | worst | confidently wrong |")
        print("| --- | --- | --- | --- | --- |")
        for what in dict.fromkeys(p["what"] for p in perturbed):
            group = [p for p in perturbed if p["what"] == what]
            for label in group[0].get("rows", {}):
                vals = [p["rows"][label]["worst_move_pct"] for p in group
                        if "rows" in p and "error" not in p["rows"][label]]
                vals = [v for v in vals if v is not None]
                wrong = sum(p["rows"][label].get("confidently_wrong", 0) for p in group if "rows" in p)
                refused = len(group) - len(vals)
                print(f"| {what} | {label} | {fmt(np.median(vals) if vals else None, '.1f', ' %')} | "
                      f"{fmt(np.max(vals) if vals else None, '.1f', ' %')} | {wrong}"
                      + (f" ({refused} refused)" if refused else "") + " |")
    if args.json:
        Path(args.json).write_text(json.dumps({"cases": results, "perturbations": perturbed}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
