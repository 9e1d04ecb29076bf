"""`adxlgw diagnose` on the Leiria robot recordings, as a user would run it.

    python -m benchmarks.accuracy.diagnosis_real_data datasets/leiria-robot/eV50p_MPU6050RM3100.csv \
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

from benchmarks.harness import stamp
from gateway.cli import main as adxlgw
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import write_recording

REPO = Path(__file__).resolve().parents[2]


def convert(src: Path, dst: Path) -> None:
    d = np.genfromtxt(src, delimiter=",", names=True)
    write_recording(dst, {"source": "import", "origin": src.name, "axis": "x"}, {
        "t_s": d["sensor_time_s"], "acc_x_mps2": d["acc_z_g"] * G, "acc_y_mps2": d["acc_y_g"] * G,
        "t_host_s": d["arrival_time_s"], "ref_pos_m": d["ref_z_m"],
    })


def facts(src: Path) -> list[str]:
    """What the baseline simulation assumes, measured on the file: noise at rest, the
    robot's vibration at rest and at speed, arrival timing, the reference's quality."""
    from scipy.signal import welch

    from gateway.core.diagnosis.context import reference_resolution_block

    d = np.genfromtxt(src, delimiter=",", names=True)
    t, acc = d["sensor_time_s"], d["acc_z_g"] * G
    period = float(np.median(np.diff(t)))
    fs = 1.0 / period
    rest = d["robot_at_rest"] > 0.5
    out = [f"file: {src.name}, {t.size} samples, period {period * 1e3:.2f} ms"]
    # each stretch where the robot's z stands: the first is a true standstill (the
    # sensor's own noise), later ones follow a move (settling) or have the robot moving
    # sideways (z still, the arm vibrating)
    segs = [s for s in np.split(np.arange(t.size), np.flatnonzero(np.diff(rest.astype(int))) + 1) if rest[s[0]]]
    for k, s in enumerate(segs):
        r = acc[s] - acc[s].mean()
        what = "before the first move" if k == 0 else ("after the last z move" if k == len(segs) - 1 else "a stop")
        line = f"z standing {t[s[0]]:.2f}–{t[s[-1]]:.2f} s ({what}): {r.std() / G * 1e3:.1f} mg RMS"
        if k == 0:
            line += (f" = {r.std() / G / np.sqrt(fs / 2) * 1e6:.0f} µg/√Hz if white over 0–{fs / 2:.0f} Hz "
                     "(ADXL202 model: 200 µg/√Hz, 1.8 mg in its 50 Hz)")
        out.append(line)
    # the robot's vibration: spectra at rest and at speed (|v| > 0.1 m/s and nearly constant)
    vel = d["ref_vz_mps"]
    cruise = (np.abs(vel) > 0.1) & (np.abs(np.gradient(vel, t)) < 0.2)
    first_rest = np.zeros(t.size, dtype=bool)
    first_rest[segs[0]] = True
    for name, mask in (("standstill", first_rest), ("at speed", cruise)):
        segs = [s for s in np.split(np.arange(t.size), np.flatnonzero(np.diff(mask.astype(int))) + 1)
                if mask[s[0]] and s.size >= 32]
        if not segs:
            continue
        psd = []
        for s in segs:
            f, p = welch(acc[s] - acc[s].mean(), fs=fs, nperseg=32)
            psd.append(p * s.size)
        p = np.sum(psd, axis=0) / sum(s.size for s in segs)
        top = np.argsort(-p[1:])[:3] + 1
        rms = np.sqrt(np.concatenate([acc[s] - acc[s].mean() for s in segs]).var())
        out.append(f"{name}: {sum(s.size for s in segs)} samples, {rms / G * 1e3:.2f} mg RMS; strongest bands "
                   + ", ".join(f"{f[i]:.0f} Hz ({np.sqrt(p[i]) / G * 1e6:.0f} µg/√Hz)" for i in top))
    # arrival timing
    delay = d["arrival_time_s"] - t
    gaps = np.diff(d["arrival_time_s"])
    out.append(f"arrival − sensor time: median {np.median(delay) * 1e3:.1f} ms, "
               f"5–95 % {np.quantile(delay, 0.05) * 1e3:.1f}"
               f"–{np.quantile(delay, 0.95) * 1e3:.1f} ms; arrival gaps < 4 ms: {np.mean(gaps < 4e-3) * 100:.0f} % "
               f"(bursts; the board's link would give one per period)")
    # the reference: its interval and how steady a cruise looks through it
    pos = d["ref_z_m"]
    moving = np.abs(np.gradient(pos, t)) > 1e-6
    step = reference_resolution_block(t, pos, moving)
    slope = np.diff(pos) / np.diff(t)
    knot = np.flatnonzero(np.abs(np.diff(slope)) > 0.1 * np.abs(np.diff(slope)).max()) + 1
    seg_v = np.diff(pos[knot]) / np.diff(t[knot])
    seg_t = np.diff(t[knot])
    steady = np.abs(seg_v) > 0.1
    # on a cruise the robot's speed is steady: the spread of segment speeds is the
    # reference's timing noise (δt ≈ interval · δv / v)
    rel = np.abs(np.diff(seg_v[steady])) / np.abs(seg_v[steady][1:])
    out.append(f"reference: a position that bends every {step} samples "
               f"(median {np.median(seg_t) * 1e3:.0f} ms between its own samples); "
               f"consecutive segment speeds while moving differ by {np.median(rel) * 100:.0f} % (median), "
               f"i.e. its timestamps scatter by ~{np.median(rel) * np.median(seg_t) * 1e3:.0f} ms")
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("leiria_csv")
    p.add_argument("--out", default="/tmp", help="directory for the converted recording and the JSON")
    p.add_argument("--report", action="store_true", help="also write the Markdown report with plots")
    p.add_argument("--reference-block", type=int, metavar="N",
                   help="passed on to diagnose (1: compare every sample, as the design before issue 14 did)")
    p.add_argument("--facts", action="store_true",
                   help="also print what the simulation assumes, measured on the file (noise, vibration, timing, "
                        "reference)")
    args = p.parse_args()
    stamp("benchmarks.accuracy.diagnosis_real_data")
    src = Path(args.leiria_csv)
    if args.facts:
        print("\n".join(facts(src)), flush=True)
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
