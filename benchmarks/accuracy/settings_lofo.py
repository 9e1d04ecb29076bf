"""A setting of the estimator chosen leave-one-file-out on the corpus's real recordings.

    nice .venv/bin/python -m benchmarks.accuracy.settings_lofo --setting standstill_window_s \\
        --values 0.05,0.07,0.1,0.15

The issue's rule for every choice of the design: judged on the corpus, and never chosen on
the file it is scored on. For each candidate value the six robot recordings (sensor clock)
and the simulator's robot-like path (seeds 0 … --seeds − 1) are estimated in the runs the
corpus scores (realtime and smoothed, without and with the machine's hint, the hint moved
by ±50 ms: estimation_corpus's cases and score). Then, for each robot file held out, the
value is chosen on the other five and the simulator by one objective, stated once:

1. fewest confidently wrong rest ends (more than 3σ off, not flagged: never confidently
   wrong comes first);
2. then the smallest worst move over the files and runs (% of the move: no collapse on
   any file, any run);
3. then the smallest median of the worst moves.

and the held-out file is scored with the value chosen without it. Printed: per fold the
value chosen and the held-out file's scores with it and with the shipped value; the
corpus's median and worst worst-move and its confidently wrong count under the
leave-one-file-out choice and under the shipped value.
"""
from __future__ import annotations

import argparse
import datetime
import multiprocessing

import numpy as np

from benchmarks.accuracy.estimation_corpus import (
    ROBOT_FILES,
    numeric_settings,
    robot_case,
    score,
    shifted,
    sim_robot_case,
)
from benchmarks.harness import machine
from gateway.core.estimator_settings import EstimatorSettings

#: the runs scored per case: (label, method, hint shift in s; None: no hint)
RUNS = (("realtime", "realtime", None), ("realtime hint", "realtime", 0.0), ("smoothed", "smoothed", None),
        ("smoothed hint", "smoothed", 0.0), ("realtime hint −50 ms", "realtime", -0.05),
        ("realtime hint +50 ms", "realtime", 0.05))


def scores_of(job: tuple) -> tuple[str, float, dict]:
    """Every run of one case with one value of the setting: {run: (worst move %, wrong)}."""
    kind, key, name, value = job
    case = robot_case(key, "sensor") if kind == "robot" else sim_robot_case(key)
    out = {}
    for label, method, shift in RUNS:
        hint = None if shift is None else (shifted(case.rest, case.t_s, shift) if shift else case.rest)
        r = score(case, method, hint, {name: value})
        out[label] = (r.get("worst_move_pct"), r.get("confidently_wrong") or 0, r.get("error"))
    return case.name, value, out


def objective(table: dict, files: list[str], value: float) -> tuple[int, float, float]:
    """(confidently wrong rest ends, worst move %, median worst move %) over these files' runs."""
    wrong = 0
    moves = []
    for f in files:
        for worst, cw, err in table[(f, value)].values():
            wrong += cw
            moves.append(1e6 if err or worst is None else worst)  # a refusal is the worst
    return wrong, float(np.max(moves)), float(np.median(moves))


def main() -> int:
    numeric = numeric_settings()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setting", required=True, choices=numeric, metavar="NAME",
                        help="a numeric EstimatorSettings field")
    parser.add_argument("--values", required=True, help="comma-separated candidate values")
    parser.add_argument("--seeds", type=int, default=3, help="simulator seeds in every fold's choice")
    args = parser.parse_args()
    try:
        values = [float(v) for v in args.values.split(",")]
    except ValueError:
        parser.error(f"--values {args.values}: not comma-separated numbers")
    shipped = getattr(EstimatorSettings, args.setting)
    if shipped not in values:
        values.append(shipped)
    print(f"command: python -m benchmarks.accuracy.settings_lofo --setting {args.setting} --values {args.values}"
          f" --seeds {args.seeds}")
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    jobs = [("robot", n, args.setting, v) for n in ROBOT_FILES for v in values]
    jobs += [("sim", s, args.setting, v) for s in range(args.seeds) for v in values]
    with multiprocessing.get_context("spawn").Pool(2) as pool:
        results = pool.map(scores_of, jobs, chunksize=1)
    table = {(name, value): runs for name, value, runs in results}
    real = list(dict.fromkeys(name for (kind, *_), (name, _, _) in zip(jobs, results, strict=True) if kind == "robot"))
    sims = list(dict.fromkeys(name for (kind, *_), (name, _, _) in zip(jobs, results, strict=True) if kind == "sim"))
    print(f"\nsetting {args.setting}: shipped {shipped:g}; candidates {', '.join(f'{v:g}' for v in values)}")
    print("objective: fewest confidently wrong rest ends, then the smallest worst, then median, worst move over "
          "files × runs "
          f"({', '.join(r[0] for r in RUNS)})\n")
    print("| held-out file | chosen on the others | held out, chosen: wrong; median / worst move | "
          "held out, shipped |")
    print("| --- | --- | --- | --- |")
    chosen_rows, shipped_rows = [], []
    for held in real:
        others = [f for f in real if f != held] + sims
        best = min(values, key=lambda v: objective(table, others, v))
        chosen_rows.append(table[(held, best)])
        shipped_rows.append(table[(held, shipped)])
        print(f"| {held} | {best:g} | {cell(table[(held, best)])} | {cell(table[(held, shipped)])} |")
    print()
    for label, rows in (("leave-one-file-out", chosen_rows), ("shipped", shipped_rows)):
        moves = [w for runs in rows for w, _, err in runs.values() if w is not None and not err]
        wrong = sum(cw for runs in rows for _, cw, _ in runs.values())
        print(f"{label}: robot ×{len(rows)} × {len(RUNS)} runs: worst move median {np.median(moves):.1f} %, "
              f"worst {max(moves):.1f} %; confidently wrong {wrong}")
    return 0


def cell(runs: dict) -> str:
    moves = [w for w, _, err in runs.values() if w is not None and not err]
    wrong = sum(cw for _, cw, _ in runs.values())
    return f"{wrong}; {np.median(moves):.1f} / {max(moves):.1f} %" if moves else f"{wrong}; —"


if __name__ == "__main__":
    raise SystemExit(main())
