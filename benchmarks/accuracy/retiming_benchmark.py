"""Re-timing foreign loggers' arrival times, scored on the Leiria robot recordings.

    python -m benchmarks.accuracy.retiming_benchmark

For each file of datasets/leiria-robot/ (V1000_LSM9DS0.csv is held out: reported, never
tuned on), three imports with `adxlgw import`: on the sensor's own clock
(`--time-col sensor_time_s`), on the raw arrival times taken as sample times
(`--time-col arrival_time_s`, what the importer did before it could re-time), and
re-timed from the arrival times (`--arrival-col arrival_time_s`), without and with the
sensor's configured rate (`--nominal-rate-hz`, from the dataset README). Prints the re-timing's
report and its error against the sensor clock, then `adxlgw estimate` on each import:
the worst move's displacement error, per move between two of the robot's rests
(`robot_at_rest`), as the dataset's README scores it. One process.
"""
from __future__ import annotations

import contextlib
import io
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks import harness
from gateway.cli import main as adxlgw
from gateway.core.evaluation import move_errors
from gateway.offline.recording import HINT_COLUMN, read_recording

REPO = Path(__file__).resolve().parents[2]

LEIRIA = REPO / "datasets" / "leiria-robot"
# file, role, the sensor's configured rate (the dataset README's period: 11.5 ms, 10.0 ms)
FILES = (("eV50p_MPU6050RM3100.csv", "tuning", 1 / 0.0115), ("V1000_LSM9DS0.csv", "HELD OUT", 100.0))
RETIME = ["--arrival-col", "arrival_time_s", "--check-time-col", "sensor_time_s"]
TIMINGS = {
    "sensor clock": ["--time-col", "sensor_time_s"],
    "arrival times as they are": ["--time-col", "arrival_time_s"],
    "re-timed arrival times": RETIME,
    "re-timed, nominal rate given": RETIME + ["--nominal-rate-hz", "{nominal}"],
}
METHODS = ("paper", "realtime", "smoothed")
MIN_MOVE_M = 0.05  # the README's moves are 327–961 mm; smaller steps between rests are not moves


def run(*args) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = adxlgw([str(a) for a in args])
    return code, err.getvalue()


def worst_move_percent(recording: Path, estimate: Path) -> tuple[float, list[str]]:
    """Per move between two rests of the hint column (`evaluation.move_errors`, as the
    estimation benchmark scores: from the end of one rest to the end of the next):
    |estimated − robot| displacement, % of the move."""
    rec = read_recording(recording)
    pos = np.genfromtxt(estimate, delimiter=",", names=True, comments="#")["pos_m"]
    worst, moves = 0.0, []
    for m in move_errors(pos, rec.columns["ref_pos_m"], rec.columns[HINT_COLUMN] == 1, min_move_m=MIN_MOVE_M):
        pct = 100.0 * abs(m.error_m) / abs(m.ref_m)
        worst = max(worst, pct)
        moves.append(f"{m.ref_m * 1e3:+.0f} mm: {pct:.1f} %")
    return worst, moves


def main() -> int:
    harness.stamp("benchmarks.accuracy.retiming_benchmark")
    with tempfile.TemporaryDirectory() as tmp:
        for name, role, nominal in FILES:
            print(f"\n## {name} ({role})")
            scores = {}
            for timing, flags in TIMINGS.items():
                rec = Path(tmp) / "rec.csv"
                flags = [f.format(nominal=f"{nominal:.3f}") for f in flags]
                code, err = run("import", LEIRIA / name, *flags, "--acc-col", "acc_z_g", "--acc-unit", "g",
                                "--ref-pos-col", "ref_z_m", "--ref-vel-col", "ref_vz_mps",
                                "--hint-col", "robot_at_rest", "--out", rec)
                if code:
                    print(f"{timing}: import refused (exit {code}): {err.strip()}")
                    continue
                if timing.startswith("re-timed"):
                    print(f"{timing}:")
                    print("\n".join("    " + line for line in err.strip().splitlines()[1:]))
                for method in METHODS:
                    est = Path(tmp) / "est.csv"
                    code, err = run("estimate", rec, "--method", method, "--out", est)
                    scores[timing, method] = (worst_move_percent(rec, est) if code == 0
                                              else (float("nan"), [err.strip().splitlines()[-1]]))
            print("\nworst move's displacement error (per move in brackets)")
            print("| timing | " + " | ".join(METHODS) + " |")
            print("| --- |" + " --- |" * len(METHODS))
            for timing in TIMINGS:
                cells = [f"{scores[timing, m][0]:.1f} % ({'; '.join(scores[timing, m][1])})"
                         if (timing, m) in scores else "import refused" for m in METHODS]
                print(f"| {timing} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
