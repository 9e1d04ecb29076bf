"""The diagnosis of the real recordings, this checkout beside others: a change to the
diagnosis measured on data the project did not make, before against after.

    .venv/bin/python -m benchmarks.tools.diagnosis_real_compare [--compare DIR ...]

The two Leiria robot files (each at the default comparison and at every sample, as
docs/diagnosis.md §9) and the two hand-lifted airbrakes recordings that return to their
start (§8), each diagnosed by each checkout's own code (`--compare DIR`: a worktree of
another commit, e.g. `git worktree add /work/w_old f9f192b`), with this interpreter.
Printed per recording and checkout: the effects named, the negligible ones, the not
physical ones, and whether the residual is white.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.harness import machine

ROOT = Path(__file__).resolve().parents[2]

ROBOT = ("eV50p_MPU6050RM3100", "V1000_LSM9DS0")
AIRBRAKES = ("zplus", "zminus")


def _run(checkout: Path, argv: list[str]) -> None:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    subprocess.run([sys.executable, *argv], cwd=checkout, env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


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
    for name in ROBOT:
        for label, extra in (("default comparison", []), ("every sample", ["--reference-block", "1"])):
            where = tmp / f"{name}-{len(extra)}"
            _run(checkout, [*_real_data_command(checkout), str(data / "leiria-robot" / f"{name}.csv"),
                            "--out", str(where), *extra])
            out[f"robot {name}, {label}"] = json.loads(next(where.glob("*.diagnosis.json")).read_text())
    for name in AIRBRAKES:
        rec, result = tmp / f"{name}.csv", tmp / f"{name}.json"
        _run(checkout, ["-m", "gateway.cli", "import", str(data / "airbrakes-imu" / f"{name}.csv"),
                        "--time-col", "timestamp", "--time-unit", "ns", "--acc-col", "scaledAccelZ",
                        "--acc-y-col", "scaledAccelX", "--acc-unit", "g", "--out", str(rec)])
        _run(checkout, ["-m", "gateway.cli", "diagnose", str(rec), "--returns-to-start", "--json", str(result)])
        out[f"airbrakes {name}, returns to start"] = json.loads(result.read_text())
    return out


def summary(d: dict) -> str:
    named = ", ".join(e["name"] for e in d["effects"]) or "nothing"
    negligible = ", ".join(n["name"] for n in d.get("negligible", [])) or "–"
    not_physical = ", ".join(n["shape"] for n in d.get("not_physical", [])) or "–"
    return f"named {named}; negligible {negligible}; not physical {not_physical}; white {d['residual_white']}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", type=Path, action="append", default=[], help="another checkout (repeatable)")
    args = ap.parse_args()
    print("command: .venv/bin/python -m benchmarks.tools.diagnosis_real_compare "
          + " ".join(f"--compare {c}" for c in args.compare))
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    checkouts = [ROOT, *[c.resolve() for c in args.compare]]
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
        same = all(summary(results[c][case]) == summary(results[ROOT][case]) for c in checkouts)
        print(f"  {'same' if same else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
