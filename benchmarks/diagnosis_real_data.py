"""`adxlgw diagnose` on the Leiria robot recordings, as a user would run it.

    PYTHONPATH=. python benchmarks/diagnosis_real_data.py datasets/leiria-robot/eV50p_MPU6050RM3100.csv \
        [--out DIR] [--report]

The file (datasets/leiria-robot/README.md) becomes an acceleration-form recording:
t_s = sensor_time_s (the sensor's own clock), the measured axis = acc_z_g (the robot's
vertical, +1 g at rest: the fitted offset takes it), the other axis = acc_y_g (it moves
sideways at the end: no --other-axis-still), t_host_s = arrival_time_s, and the
reference = ref_z_m only — the robot's ~14 Hz position as a user has it; velocity and
acceleration are derived by diagnose, which compares at the reference's resolution.
Then `adxlgw diagnose OUT.csv --json OUT.json` runs on it.

datasets/leiria-robot/V1000_LSM9DS0.csv is held out of the design (datasets/README.md):
run it once, to report.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from gateway.cli import main as adxlgw  # noqa: E402
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G  # noqa: E402
from gateway.recording import write_recording  # noqa: E402


def convert(src: Path, dst: Path) -> None:
    d = np.genfromtxt(src, delimiter=",", names=True)
    write_recording(dst, {"source": "import", "origin": src.name, "axis": "x"}, {
        "t_s": d["sensor_time_s"], "acc_x_mps2": d["acc_z_g"] * G, "acc_y_mps2": d["acc_y_g"] * G,
        "t_host_s": d["arrival_time_s"], "ref_pos_m": d["ref_z_m"],
    })


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("leiria_csv")
    p.add_argument("--out", default="/tmp", help="directory for the converted recording and the JSON")
    p.add_argument("--report", action="store_true", help="also write the Markdown report with plots")
    p.add_argument("--reference-block", type=int, metavar="N",
                   help="passed on to diagnose (1: compare every sample, as the design before issue 14 did)")
    args = p.parse_args()
    src = Path(args.leiria_csv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rec = out / f"{src.stem}.recording.csv"
    convert(src, rec)
    cmd = ["diagnose", str(rec), "--json", str(out / f"{src.stem}.diagnosis.json")]
    if args.reference_block is not None:
        cmd += ["--reference-block", str(args.reference_block)]
    if args.report:
        cmd += ["--report", str(out / f"{src.stem}-report")]
    print("adxlgw " + " ".join(cmd), flush=True)
    return adxlgw(cmd)


if __name__ == "__main__":
    sys.exit(main())
