"""The horizontal robot moves (datasets/leiria-robot/*_y605.csv): what the diagnosis finds,
and the extended model's gain measured predictively — fitted on one sensor's recording,
applied to the other sensors' recordings of the same move.

    .venv/bin/python -m benchmarks.accuracy.diagnosis_horizontal [--out DIR] [--model-with tilt]

Each file becomes an acceleration-form recording: t_s = sensor_time_s (the sensor's own
clock), the measured axis = acc_along_g (parallel to the robot's y; ≈ 0 g at rest), the
other axis = acc_cross_g, t_host_s = arrival_time_s, ref_pos_m = ref_m (the robot's
~14 Hz position as a user has it), standstill_hint = robot_at_rest. Then, per file:

1. `adxlgw diagnose REC --json D.json --model-out M.json --model-with NAMES`: the
   verdict, and the model (named terms, and the candidates asked for with their fitted
   parameters even where the diagnosis did not name them — the file says why);
2. `adxlgw estimate REC --method smoothed [--model M_k.json]` for every model k: the final
   position error after the move (the robot stands at 605 mm) without and with each
   sensor's model. Off the diagonal the gain is predictive: the model never saw that
   recording.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.harness import machine
from gateway.cli import main as adxlgw
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import read_recording, to_acceleration, write_recording

REPO = Path(__file__).resolve().parents[2]

FILES = ("eV50p_MPU6050RM3100_y605", "eV50p_LSM9DS0_y605", "eV50p_SENTRAL_y605", "V1000_LSM9DS0_y605")


def convert(src: Path, dst: Path) -> None:
    d = np.genfromtxt(src, delimiter=",", names=True)
    write_recording(dst, {"source": "import", "origin": src.name, "axis": "x"}, {
        "t_s": d["sensor_time_s"], "acc_x_mps2": d["acc_along_g"] * G, "acc_y_mps2": d["acc_cross_g"] * G,
        "t_host_s": d["arrival_time_s"], "ref_pos_m": d["ref_m"], "standstill_hint": d["robot_at_rest"],
    })


def quiet(argv: list[str]) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return adxlgw(argv)


def final_error_mm(rec: Path, track_csv: Path) -> float:
    """The estimate's position at the end against the reference's (the final rest)."""
    ref = to_acceleration(read_recording(rec)).reference["ref_pos_m"]
    est = np.genfromtxt(track_csv, delimiter=",", names=True, comments="#")
    return float(est["pos_m"][-1] - (ref[-1] - ref[0])) * 1e3


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=None,
                   help="working directory, kept (default: a private temporary one, removed at the end)")
    p.add_argument("--model-with", default="tilt", help="passed to diagnose --model-with (default: tilt)")
    args = p.parse_args()
    if args.out is None:
        with tempfile.TemporaryDirectory(prefix="adxlgw-diagnosis-horizontal-") as tmp:
            return run(args, Path(tmp))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return run(args, out)


def run(args, out: Path) -> int:
    """Diagnose each file in `out`, then carry each model to the others (the tables)."""
    print(f"command: .venv/bin/python -m benchmarks.accuracy.diagnosis_horizontal --model-with {args.model_with}")
    print(f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}; machine: {machine()}")
    recs, models = {}, {}
    for name in FILES:
        rec = out / f"{name}.recording.csv"
        convert(REPO / "datasets" / "leiria-robot" / f"{name}.csv", rec)
        recs[name] = rec
        d_json, m_json = out / f"{name}.diagnosis.json", out / f"{name}.model.json"
        code = quiet(["diagnose", str(rec), "--json", str(d_json), "--model-out", str(m_json),
                      "--model-with", args.model_with])
        doc = json.loads(d_json.read_text())
        if code != 0:
            print(f"{name}: diagnose exit {code}: {doc.get('error')}")
            continue
        models[name] = m_json
        named = [e["name"] + (f" (not separable from {', '.join(e['not_separable_from'])})"
                              if e.get("not_separable_from") else "") for e in doc["effects"]]
        model = json.loads(m_json.read_text())
        terms = ", ".join(f"{t['name']} " + " ".join(f"{k}={v:.4g}" for k, v in t["params"].items())
                          for t in model["effects"])
        print(f"{name}: named {', '.join(named) or 'nothing'}; model: {terms or 'no terms'}")
        for c in doc["candidates"]:
            if c["name"] in args.model_with.split(","):
                print(f"    {c['name']}: {c['status']} — {c['reason']}")
    print()
    print("final position error after the 605 mm move, mm (smoothed estimate); columns: the model fitted on")
    head = ["applied to", "no model"] + [f"{m.split('_')[0]}_{m.split('_')[1]}" for m in models]
    print(" | ".join(head))
    print(" | ".join("---" for _ in head))
    gains = {}
    for name, rec in recs.items():
        row = [name]
        track = out / "track.csv"
        quiet(["estimate", str(rec), "--method", "smoothed", "--out", str(track)])
        base = final_error_mm(rec, track)
        row.append(f"{base:+.1f}")
        for fit_on, m_json in models.items():
            quiet(["estimate", str(rec), "--method", "smoothed", "--model", str(m_json), "--out", str(track)])
            err = final_error_mm(rec, track)
            row.append(f"{err:+.1f}" + (" (own)" if fit_on == name else ""))
            if fit_on != name:
                gains.setdefault(name, []).append(abs(base) - abs(err))
        print(" | ".join(row))
    print()
    for name, g in gains.items():
        print(f"{name}: predictive gain (|error| without − with, models of the other sensors): "
              f"median {np.median(g):+.1f} mm, worst {min(g):+.1f} mm")
    positive = sum(np.median(g) > 0 for g in gains.values())
    print(f"files with a positive median predictive gain: {positive} of {len(gains)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
