"""Accuracy of the four estimators on the paper's experiment and on real recordings.

    python -m benchmarks.accuracy.estimation_benchmark [--seeds 20] [--img docs/img]

Part 1 — what `adxlgw simulate --scenario paper --strokes 10 --seed S` writes, for
S = 0…19 (data-sheet noise), read back as `adxlgw estimate` reads it; errors against the
recording's reference at the last sample of each stop. Methods: raw, paper, realtime,
smoothed, and the noise floor (the realtime filter fed z − b_true and told the bias is
exactly zero).
Part 2 — the real recordings datasets/airbrakes-imu/{zplus,zminus}.csv,
imported with `adxlgw import` (Z axis, X as second axis), settings from their own
initial rest; they end where they began, so the final position is the error. The
recordings' gyroscope (not part of the one-axis recording) tells how much of that
error the hand's rotation explains.
Part 3 — the Leiria robot recordings (datasets/leiria-robot: an IMU on an industrial robot
moving in straight lines), imported with `adxlgw import` on the sensor clock and on the
logger's arrival times, settings as `adxlgw estimate` picks them; per move between two
rests of the robot, the estimated displacement against the robot's; paper, realtime and
smoothed, with and without the robot's "in position" state as the standstill hint. The
held-out file (V1000_LSM9DS0.csv) is reported separately.
Prints the tables; writes plots to --img. Uses at most two processes.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import multiprocessing
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from gateway.cli import main as adxlgw
from gateway.commands.estimate import settings_for
from gateway.core.drift_model import drift_g
from gateway.core.estimator import EstimateTrack, estimate_series
from gateway.core.estimator_settings import from_rest, from_sensor_model
from gateway.core.evaluation import move_errors, summarise_errors
from gateway.core.reference_point import find_initial_rest
from gateway.core.sensor_model import SensorParams
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G
from gateway.offline.recording import read_recording, to_acceleration

REPO = Path(__file__).resolve().parents[2]

METHODS = ("raw", "paper", "realtime", "smoothed", "floor")
DATASETS = REPO / "datasets" / "airbrakes-imu"
ROBOT = REPO / "datasets" / "leiria-robot"
DESIGN_FILE = "eV50p_MPU6050RM3100.csv"  # used in design decisions (datasets/README.md)
HELD_OUT_FILE = "V1000_LSM9DS0.csv"  # never used to choose anything: run and reported only
CLOCKS = {"sensor": "sensor_time_s", "arrival": "arrival_time_s"}


def quiet_adxlgw(argv: list[str]) -> int:
    """The command, with its progress lines on stderr swallowed."""
    with open(os.devnull, "w") as null, contextlib.redirect_stderr(null):
        return adxlgw(argv)


def simulated_recording(seed: int, workdir: str):
    path = os.path.join(workdir, f"paper_{seed}.csv")
    code = quiet_adxlgw(["simulate", "--scenario", "paper", "--strokes", "10", "--seed", str(seed), "--out", path])
    assert code == 0
    return to_acceleration(read_recording(path))


def run_seed(seed: int) -> dict:
    sensor = SensorParams()
    settings = from_sensor_model(sensor)
    with tempfile.TemporaryDirectory() as tmp:
        series = simulated_recording(seed, tmp)
    ref = series.reference
    true_bias = (sensor.x.zero_g_offset_g + drift_g(series.t_s, sensor.x.drift)) * G
    out = {}
    for name in METHODS:
        method = "realtime" if name == "floor" else name
        extra = {"known_bias_mps2": true_bias} if name == "floor" else {}
        track = estimate_series(series.t_s, series.acc_mps2, series.valid, method=method, settings=settings,
                                lost_before=series.lost_before, **extra)
        s = summarise_errors(series.t_s, track.pos_m, ref["ref_pos_m"], ref["ref_vel_mps"], ref["ref_acc_mps2"],
                             track.vel_mps)
        out[name] = {
            "stops": [abs(st.error_m) for st in s.stops],
            "rms": s.rms_m,
            "vel_rms": s.vel_rms_mps,
            "moving_max": s.moving_max_m,
            "travelled": s.travelled_m,
        }
    return out


def table(results: list[dict]) -> list[str]:
    head = ("| method | median abs. error at 1st stop | at 10th stop | % of distance travelled (10th stop) "
            "| position RMS | velocity RMS | max. position error in motion |")
    lines = [head, "|" + " --- |" * 7]
    for name in METHODS:
        first = np.median([r[name]["stops"][0] for r in results])
        tenth = np.median([r[name]["stops"][9] for r in results])
        travelled = results[0][name]["travelled"]
        rms = np.median([r[name]["rms"] for r in results])
        vel = np.median([r[name]["vel_rms"] for r in results])
        mx = np.median([r[name]["moving_max"] for r in results])
        label = "noise floor (realtime told the true bias)" if name == "floor" else name
        lines.append(f"| {label} | {first * 1e3:.3g} mm | {tenth * 1e3:.3g} mm | {100 * tenth / travelled:.2g} % "
                     f"| {rms * 1e3:.3g} mm | {vel * 1e3:.3g} mm/s | {mx * 1e3:.3g} mm |")
    return lines


def plot_paper_figures(img: Path, results: list[dict]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sensor = SensorParams()
    settings = from_sensor_model(sensor)
    with tempfile.TemporaryDirectory() as tmp:
        series = simulated_recording(0, tmp)
    ref = series.reference
    t = series.t_s
    written = []
    tracks = {m: estimate_series(t, series.acc_mps2, series.valid, method=m, settings=settings,
                                 lost_before=series.lost_before) for m in ("raw", "paper", "realtime", "smoothed")}
    for name, title, fname in (
        ("raw", "raw double integration (the paper's fig. 6): drift without bound", "estimation_fig6_raw.png"),
        ("paper", "reference point + the paper's Kalman filter (the paper's fig. 7): still drifts",
         "estimation_fig7_paper.png"),
    ):
        fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
        axes[0].plot(t, tracks[name].vel_mps, label="estimate")
        axes[0].plot(t, ref["ref_vel_mps"], "k--", lw=1, label="truth")
        axes[0].set_ylabel("velocity (m/s)")
        axes[1].plot(t, tracks[name].pos_m, label="estimate")
        axes[1].plot(t, ref["ref_pos_m"], "k--", lw=1, label="truth")
        axes[1].set_ylabel("position (m)")
        axes[1].set_xlabel("time (s)")
        for ax in axes:
            ax.legend()
            ax.grid(alpha=0.3)
        axes[0].set_title(f"{title} — seed 0")
        fig.tight_layout()
        fig.savefig(img / fname, dpi=90)
        plt.close(fig)
        written.append(fname)
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    still = tracks["realtime"].standstill
    for ax in axes:
        ax.fill_between(t, 0, 1, where=still, transform=ax.get_xaxis_transform(), color="0.92", lw=0)
    for name in ("realtime", "smoothed"):
        axes[0].plot(t, tracks[name].pos_m, label=name)
        axes[1].plot(t, (tracks[name].vel_mps - ref["ref_vel_mps"]) * 1e3, label=name, lw=0.8)
        axes[2].plot(t, (tracks[name].pos_m - ref["ref_pos_m"]) * 1e3, label=name)
    axes[2].fill_between(t, -2e3 * tracks["realtime"].pos_std_m, 2e3 * tracks["realtime"].pos_std_m, alpha=0.2,
                         label="±2σ realtime")
    axes[0].plot(t, ref["ref_pos_m"], "k--", lw=1, label="truth")
    axes[0].set_ylabel("position (m)")
    axes[1].set_ylabel("velocity error (mm/s)")
    axes[2].set_ylabel("position error (mm)")
    axes[2].set_xlabel("time (s) — grey: detected standstill")
    for ax in axes:
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title("the gateway's estimator, realtime and smoothed — seed 0")
    fig.tight_layout()
    fig.savefig(img / "estimation_gateway.png", dpi=90)
    plt.close(fig)
    written.append("estimation_gateway.png")
    fig, ax = plt.subplots(figsize=(8, 5))
    stops = np.arange(1, 11)
    for name in METHODS:
        med = [np.median([r[name]["stops"][i] for r in results]) * 1e3 for i in range(10)]
        ax.semilogy(stops, med, "o-", label="noise floor" if name == "floor" else name)
    ax.set_xlabel("stop")
    ax.set_ylabel(f"median |position error| over {len(results)} seeds (mm)")
    ax.grid(which="both", alpha=0.3)
    ax.legend()
    ax.set_title("error at each stop, paper experiment (10 strokes of 0.3 m)")
    fig.tight_layout()
    fig.savefig(img / "estimation_error_growth.png", dpi=90)
    plt.close(fig)
    written.append("estimation_error_growth.png")
    return written


def strapdown_vertical(source: Path) -> np.ndarray:
    """What a gyro-aided estimator would integrate: all three accelerometer axes rotated
    into the frame the sensor had at rest (gyroscope integrated by Rodrigues steps, its
    bias from the first 0.5 s), projected on the vertical of that rest, in m/s² — gravity
    included, like the one-axis reading. One value per raw row (the rows the import keeps).
    Not available to the gateway (one axis, no gyroscope); used to say what limits it."""
    rows = []
    with open(source, newline="") as fh:
        for r in csv.DictReader(fh):
            if r["scaledAccelZ"] and r["scaledGyroX"]:
                rows.append((int(r["timestamp"]), *(float(r[f"scaledGyro{a}"]) for a in "XYZ"),
                             *(float(r[f"scaledAccel{a}"]) for a in "XYZ")))
    data = np.array(rows, dtype=float)
    t = (data[:, 0] - data[0, 0]) * 1e-9
    w = data[:, 1:4] - data[:500, 1:4].mean(axis=0)
    f = data[:, 4:7] * G
    up0 = f[:500].mean(axis=0)
    up0 /= np.linalg.norm(up0)  # the rest's vertical, in the sensor frame at rest
    R = np.eye(3)  # sensor frame now → sensor frame at rest
    vertical = np.empty(t.size)
    for k in range(t.size):
        vertical[k] = up0 @ (R @ f[k])
        if k + 1 < t.size:
            phi = w[k] * (t[k + 1] - t[k])
            a = np.linalg.norm(phi)
            if a > 0:
                kx = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]) / a
                R = R @ (np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx)
    return vertical


def real_data(img: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["| recording | method | final position (= error) | standstill at the end | "
             "same estimator on the gyro-aided vertical (3 axes + gyroscope) |", "|" + " --- |" * 5]
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex="col")
    for col, name in enumerate(("zplus", "zminus")):
        source = DATASETS / f"{name}.csv"
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, f"{name}.csv")
            code = quiet_adxlgw(["import", str(source), "--time-col", "timestamp", "--time-unit", "ns", "--acc-col",
                           "scaledAccelZ", "--acc-y-col", "scaledAccelX", "--acc-unit", "g", "--out", path])
            assert code == 0
            series = to_acceleration(read_recording(path))
        t = series.t_s
        period = float(np.median(np.diff(t)))
        rest = find_initial_rest(series.acc_mps2, series.valid, period)
        settings = from_rest(series.acc_mps2[rest.start:rest.stop], period)
        vertical = strapdown_vertical(source)
        assert vertical.size == t.size
        sign = np.sign(np.mean(series.acc_mps2[rest.start:rest.stop]))  # zminus: the axis points down
        aided_acc = sign * vertical
        aided_settings = from_rest(aided_acc[rest.start:rest.stop], period)
        for method in ("raw", "paper", "realtime", "smoothed"):
            track: EstimateTrack = estimate_series(t, series.acc_mps2, series.valid, method=method, settings=settings)
            untilted = estimate_series(t, aided_acc, series.valid, method=method, settings=aided_settings)
            at_end = "yes" if track.standstill[-1] else "no"
            lines.append(f"| {name} | {method} | {track.pos_m[-1] * 1e3:+.1f} mm | {at_end} | "
                         f"{untilted.pos_m[-1] * 1e3:+.1f} mm |")
            if method in ("paper", "smoothed"):
                axes[0, col].plot(t, track.pos_m, label=method)
                axes[1, col].plot(t, track.vel_mps, label=method, lw=0.8)
            if method == "smoothed":
                axes[0, col].plot(t, untilted.pos_m, "--", label="smoothed, on the gyro-aided vertical")
        axes[0, col].set_title(f"{name}: up ~0.3 m and back, at rest at both ends")
        axes[0, col].set_ylabel("position (m)")
        axes[1, col].set_ylabel("velocity (m/s)")
        axes[1, col].set_xlabel("time (s)")
        axes[1, col].set_ylim(-2.5, 2.5)
        for ax in axes[:, col]:
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(img / "estimation_real.png", dpi=90)
    plt.close(fig)
    return lines


def robot_run(name: str, clock: str) -> dict:
    """One robot file read as a user would: `adxlgw import` on the chosen clock (z axis, g),
    settings as `adxlgw estimate` picks them (the recording's own initial rest), every
    method; the robot's z and its "in position" state (the hint) by row — the importer of
    today carries no reference columns, and keeps every row of these files."""
    source = ROBOT / name
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "imported.csv")
        code = quiet_adxlgw(["import", str(source), "--time-col", CLOCKS[clock], "--acc-col", "acc_z_g",
                             "--acc-unit", "g", "--out", path])
        if code != 0:
            return {"error": f"adxlgw import exited {code}"}
        series = to_acceleration(read_recording(path))
    raw = np.genfromtxt(source, delimiter=",", names=True)
    assert raw.size == series.t_s.size
    ref, hint = raw["ref_z_m"], raw["robot_at_rest"]
    t = series.t_s
    out = {"t": t, "ref": ref, "hint": hint, "period_ms": float(np.median(np.diff(t))) * 1e3, "runs": {}}
    try:
        settings = settings_for(series, "acceleration", "auto", None)
    except Exception as err:  # noqa: BLE001 — reported in the table, as the command would
        out["error"] = f"{type(err).__name__}: {err}"
        return out
    for method, use_hint in (("paper", False), ("realtime", False), ("realtime", True), ("smoothed", False),
                             ("smoothed", True)):
        try:
            track = estimate_series(t, series.acc_mps2, series.valid, method=method, settings=settings,
                                    standstill_hint=hint if use_hint else None)
        except Exception as err:  # noqa: BLE001
            out["runs"][(method, use_hint)] = {"error": f"{type(err).__name__}: {err}"}
            continue
        moves = move_errors(track.pos_m, ref, hint)
        ends = np.array([m.end for m in moves])
        err_at_rest = np.abs(track.pos_m[ends] - ref[ends])
        band = 3 * track.pos_std_m[ends]
        out["runs"][(method, use_hint)] = {
            "moves": moves, "track": track, "worst_rest_error_m": float(err_at_rest.max()),
            "inside_3sigma": int(np.count_nonzero(err_at_rest <= band)) if method != "paper" else None,
            "untrusted_pct": 100.0 * float(track.untrusted.mean()) if method != "paper" else None,
        }
    return out


def robot_table(results: dict[tuple[str, str], dict]) -> list[str]:
    # the worst move is the figure; the worst position error at a rest is what a
    # user reads off the register at a stop (a move's error is the difference of two of them)
    lines = ["| file | clock | method | hint | per move: robot → estimate (mm) | worst move | "
             "worst position error at a rest | position inside ±3σ at the rests | time flagged not trustworthy |",
             "|" + " --- |" * 9]
    for (name, clock), res in results.items():
        label = name.split("_")[0]
        if "error" in res:
            lines.append(f"| {label} | {clock} | all | — | {res['error']} | — | — | — | — |")
            continue
        for (method, use_hint), run in res["runs"].items():
            hint = "yes" if use_hint else "no"
            if "error" in run:
                lines.append(f"| {label} | {clock} | {method} | {hint} | {run['error']} | — | — | — | — |")
                continue
            moves = run["moves"]
            per = ", ".join(f"{m.ref_m * 1e3:+.0f} → {m.estimate_m * 1e3:+.0f}" for m in moves)
            worst = max(m.percent for m in moves)
            inside = "—" if run["inside_3sigma"] is None else f"{run['inside_3sigma']}/{len(moves)}"
            flagged = "—" if run["untrusted_pct"] is None else f"{run['untrusted_pct']:.0f} %"
            lines.append(f"| {label} | {clock} ({res['period_ms']:.2f} ms median period) | {method} | {hint} "
                         f"| {per} | **{worst:.1f} %** | {run['worst_rest_error_m'] * 1e3:.0f} mm "
                         f"| {inside} | {flagged} |")
    return lines


def plot_robot(img: Path, name: str, res: dict) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, ref = res["t"], res["ref"]
    fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for ax in axes:
        ax.fill_between(t, 0, 1, where=res["hint"] > 0.5, transform=ax.get_xaxis_transform(), color="0.92", lw=0,
                        label="robot in position (the hint)")
    axes[0].plot(t, ref, "k", lw=2, label="robot z")
    for (method, use_hint), style in ((("paper", False), ":"), (("realtime", False), "-"), (("realtime", True), "--"),
                                      (("smoothed", True), "-.")):
        run = res["runs"].get((method, use_hint), {})
        if "track" not in run:
            continue
        label = f"{method}{' + hint' if use_hint else ''}"
        tr = run["track"]
        axes[0].plot(t, tr.pos_m, style, label=label)
        axes[1].plot(t, (tr.pos_m - ref) * 1e3, style, label=label)
        if (method, use_hint) == ("realtime", False):
            axes[1].fill_between(t, -3e3 * tr.pos_std_m, 3e3 * tr.pos_std_m, alpha=0.15, label="±3σ realtime")
            flagged = tr.untrusted
            axes[0].fill_between(t, 0, 0.05, where=flagged, transform=axes[0].get_xaxis_transform(), color="r",
                                 alpha=0.4, lw=0, label="realtime: not trustworthy (flag 256)")
    axes[0].set_ylabel("z (m)")
    axes[1].set_ylabel("error (mm)")
    axes[1].set_ylim(-150, 150)
    axes[1].set_xlabel("time on the sensor clock (s)")
    for ax in axes:
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)
    axes[0].set_title(f"{name}: position against the robot (sensor clock)")
    fig.tight_layout()
    fname = f"estimation_robot_{name.split('_')[0]}.png"
    fig.savefig(img / fname, dpi=80)
    plt.close(fig)
    return fname


def robot_data(img: Path) -> list[str]:
    lines = []
    for title, names in (("design file (used in design decisions)", (DESIGN_FILE,)),
                         ("HELD-OUT file (never used to choose anything; run and reported only)", (HELD_OUT_FILE,))):
        results = {(name, clock): robot_run(name, clock) for name in names for clock in CLOCKS}
        lines += ["", f"Leiria robot, {title}:", ""]
        lines += robot_table(results)
        for name in names:
            res = results[(name, "sensor")]
            if "runs" in res and res["runs"]:
                lines.append(f"wrote {img / plot_robot(img, name, res)}")
    return lines


def drift_identification(img: Path, hours: float) -> list[str]:
    """The paper's fig. 1 experiment: a long standstill (in memory — 12 h is 1.3 GB as CSV),
    fitted and judged exactly as `adxlgw fit-drift` does."""
    from gateway.commands.fit_drift import plot_fit, report
    from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
    from gateway.core.drift_fit import fit_drift
    from gateway.core.motion_profiles import standstill
    from gateway.core.simulator import simulate

    sensor = SensorParams()
    run = simulate(standstill(hours * 3600.0), sensor, seed=0)
    t = sample_times_s(run.t2, run.tick_hz)
    acc_g = acceleration_mps2(run.t1x, run.t2, AxisCalibration()) / G
    del run
    fit = fit_drift(t, acc_g)
    d = sensor.x.drift
    lines = [f"simulated truth: C1 = {d.c1_g * 1e3:.4f} mg, C2 = {sensor.x.zero_g_offset_g * 1e3:.4f} mg "
             f"(zero-g offset), T = {d.time_constant_s:.0f} s; {t.size / 1e6:.1f} M samples"]
    lines += report(fit)
    plot_fit(str(img / "fit_drift_12h.png"), fit, float(t[0]), f"simulated {hours:g}-hour standstill")
    lines.append(f"wrote {img / 'fit_drift_12h.png'}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--img", default=str(REPO / "docs" / "img"))
    parser.add_argument("--drift-hours", type=float, default=12.0, help="standstill for the drift fit (0: skip)")
    parser.add_argument("--robot-only", action="store_true", help="only the Leiria robot recordings")
    args = parser.parse_args()
    img = Path(args.img)
    img.mkdir(parents=True, exist_ok=True)
    harness.stamp("benchmarks.accuracy.estimation_benchmark")
    print("\n".join(robot_data(img)))
    print()
    if args.robot_only:
        return 0
    start = time.perf_counter()
    # spawned, not forked: the robot part above wrote CSV through polars, whose thread pool a
    # forked child inherits dead (its first write_csv hung forever, 2026-11-26)
    with multiprocessing.get_context("spawn").Pool(min(2, args.seeds)) as pool:
        results = pool.map(run_seed, range(args.seeds))
    print(f"paper experiment: adxlgw simulate --scenario paper --strokes 10, seeds 0–{args.seeds - 1}, "
          f"data-sheet noise; {results[0]['raw']['travelled']:.2f} m travelled; medians over the seeds "
          f"({time.perf_counter() - start:.1f} s)")
    print()
    print("\n".join(table(results)))
    print()
    ratio = [r["realtime"]["stops"][9] / r["floor"]["stops"][9] for r in results]
    print(f"realtime / noise floor at the 10th stop, per seed: median {np.median(ratio):.3f}, "
          f"max {np.max(ratio):.3f}")
    print()
    for fname in plot_paper_figures(img, results):
        print(f"wrote {img / fname}")
    print()
    if DATASETS.is_dir():
        print("real recordings (MicroStrain 3DM-CX5-AR, 1000 samples/s, hand-lifted; settings from the initial rest):")
        print()
        print("\n".join(real_data(img)))
        print(f"\nwrote {img / 'estimation_real.png'}")
    else:
        print(f"real recordings: {DATASETS} not found, skipped")
    if args.drift_hours > 0:
        print()
        print(f"zero-drift identification on a simulated {args.drift_hours:g}-hour standstill (the paper's fig. 1):")
        print("\n".join(drift_identification(img, args.drift_hours)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
