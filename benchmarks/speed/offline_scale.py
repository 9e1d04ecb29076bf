"""Offline at the paper's scale (issue 17): 12-hour recordings through the commands, timed.

    python -m benchmarks.speed.offline_scale [--hours 12] [--baseline-hours 1] [--workdir /tmp]

Makes two simulated recordings of --hours at 500 samples/s (seeded): the paper's strokes
back to back (raw form, with the truth in ref_pos_m/ref_vel_mps/ref_acc_mps2) as CSV and
Parquet, and a standstill as Parquet (for fit-drift). Then runs each command of the goals
table as a user does (`python -m gateway.cli …`, a fresh process, pinned to one core) and
measures its wall time and peak memory (the child's maximum RSS, from wait4). Linux
starts a child's maximum RSS at its parent's, so the recordings are made in a separate
process and this one stays small (~150 MB, below any command's own).

Side by side, in the same run: the plain-csv path — `adxlgw estimate` of the commit before
issue 17 (BASELINE_COMMIT: Python's csv module row by row, np.savetxt), unpacked from git
into the work directory — and today's on the same --baseline-hours file (the old path
reads the whole file as text: a 12-hour file would not fit), scaled to --hours.

The files go to a fresh directory under --workdir and are deleted at the end (a 12-hour
CSV is ~2.4 GB); the run's own cost (time, disk) is printed. Not a test: the goals are
printed, not asserted (timings on a shared machine are noisy).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import harness

REPO = Path(__file__).resolve().parents[2]

# the last commit before issue 17's recordings (the plain-csv path)
BASELINE_COMMIT = "99a982d980d96ab814b709bbf26213960010ab3c"
WRITE_ROWS = 1 << 20


def write_both(run, meta: dict[str, str], paths: list[Path], rows: int | None = None) -> None:
    from gateway.offline.recording import FORMAT_ID, ColumnWriter

    cols = run.recording_columns()
    n = len(run) if rows is None else min(rows, len(run))
    writers = [ColumnWriter(p, list(cols), {"format": FORMAT_ID, **meta}) for p in paths]
    for start in range(0, n, WRITE_ROWS):
        stop = min(n, start + WRITE_ROWS)
        for w in writers:
            w.write({k: v[start:stop] for k, v in cols.items()})
    for w in writers:
        w.commit()


def make_recordings(work: Path, hours: float, baseline_hours: float) -> None:
    from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
    from gateway.core.scenarios import ScenarioSettings, build_profile
    from gateway.core.sensor_model import SensorParams
    from gateway.core.simulator import simulate

    sensor = SensorParams()
    meta = {"tick_hz": f"{sensor.tick_hz:g}", "source": "simulation", "axis": "x", "seed": "0"}
    stroke_s = 0.4 + 1.0  # 0.3 m at 1 m/s with its ramps, then a 1 s dwell
    strokes = int(hours * 3600 / stroke_s) + 1
    run = simulate(reciprocating_strokes(StrokeSettings(strokes=strokes)), sensor, seed=0,
                   duration_s=hours * 3600 - sensor.t2_s / 2)
    files = recording_paths(work)
    write_both(run, {**meta, "scenario": "paper"}, [files["strokes.csv"], files["strokes.parquet"]])
    write_both(run, {**meta, "scenario": "paper"}, [files["baseline.csv"]],
               rows=int(baseline_hours * 3600 / sensor.t2_s))
    del run
    still = simulate(build_profile(ScenarioSettings(name="standstill", standstill_s=hours * 3600)), sensor, seed=1)
    write_both(still, {**meta, "scenario": "standstill", "seed": "1"}, [files["still.parquet"]])


def recording_paths(work: Path) -> dict[str, Path]:
    return {"strokes.csv": work / "strokes.csv", "strokes.parquet": work / "strokes.parquet",
            "baseline.csv": work / "strokes_baseline.csv", "still.parquet": work / "still.parquet"}


def timed(cmd: list[str], cwd: Path, pythonpath: Path) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of one command in a fresh process on one core. The CPU
    time (user + system, all threads) is what the command costs; the wall time also holds
    whatever else the shared core ran meanwhile."""
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    env.pop("ADXLGW_NO_JIT", None)
    core = sorted(os.sched_getaffinity(0))[0]
    start = time.perf_counter()
    proc = subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-m", "gateway.cli", *cmd], cwd=cwd,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{err}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def main() -> int:
    parser = harness.parser(__doc__)
    parser.add_argument("--hours", type=float, default=12.0)
    parser.add_argument("--baseline-hours", type=float, default=1.0,
                        help="length of the file both paths read side by side (default: 1)")
    parser.add_argument("--workdir", default="/tmp", help="where the recordings are written (default: /tmp)")
    parser.add_argument("--make-into", metavar="DIR", help=argparse.SUPPRESS)  # the recordings' own process
    args = parser.parse_args()
    if args.make_into:
        make_recordings(Path(args.make_into), args.hours, args.baseline_hours)
        return 0
    began = time.perf_counter()
    run = harness.stamp("benchmarks.speed.offline_scale")
    print("each command pinned to one core")
    work = Path(tempfile.mkdtemp(prefix="offline_scale_", dir=args.workdir))
    try:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "benchmarks.speed.offline_scale", "--hours", str(args.hours),
                        "--baseline-hours", str(args.baseline_hours), "--make-into", str(work)], check=True, cwd=REPO)
        files = recording_paths(work)
        sizes = {k: p.stat().st_size / 1e6 for k, p in files.items()}
        print(f"made the recordings in {time.perf_counter() - t0:.0f} s (not counted): "
              + ", ".join(f"{k} {v:.0f} MB" for k, v in sizes.items()))
        baseline = work / "baseline_src"
        baseline.mkdir()
        archive = subprocess.run(["git", "-C", str(REPO), "archive", BASELINE_COMMIT], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(baseline)], input=archive, check=True)
        # warm numba's cache for both trees (compilation is not what is measured)
        for tree in (REPO, baseline):
            timed(["estimate", str(files["baseline.csv"]), "--out", str(work / "warm.csv")], work, tree)

        def measure(label, cmd, tree=REPO):
            wall, cpu, rss = timed(cmd, work, tree)
            print(f"  {label}: {wall:.1f} s wall, {cpu:.1f} s CPU, peak {rss:.0f} MB", flush=True)
            return wall, cpu, rss

        scale = args.hours / args.baseline_hours
        print(f"side by side on the {args.baseline_hours:g} h CSV:")
        old_w, old_c, old_m = measure("plain-csv path (before issue 17), estimate realtime CSV → CSV",
                               ["estimate", str(files["baseline.csv"]), "--out", str(work / "old.csv")], baseline)
        new_w, new_c, new_m = measure("today, estimate realtime CSV → CSV",
                               ["estimate", str(files["baseline.csv"]), "--out", str(work / "new.csv")])
        print(f"  ratio plain-csv / today: {old_w / new_w:.1f}× wall time, {old_c / new_c:.1f}× CPU time, "
              f"{old_m / new_m:.1f}× memory")
        (work / "old.csv").unlink()
        (work / "new.csv").unlink()

        print(f"{args.hours:g} h ({int(args.hours * 1800000):,} samples):")
        s = files
        res = {
            "csv": measure("estimate --method realtime, CSV in, CSV out",
                           ["estimate", str(s["strokes.csv"]), "--out", str(work / "e.csv")]),
            "pq": measure("estimate --method realtime, Parquet in and out",
                          ["estimate", str(s["strokes.parquet"]), "--out", str(work / "e.parquet")]),
            "smoothed": measure("estimate --method smoothed, Parquet in and out",
                                ["estimate", str(s["strokes.parquet"]), "--method", "smoothed",
                                 "--out", str(work / "s.parquet")]),
            "fit": measure("fit-drift on the standstill, Parquet",
                           ["fit-drift", str(s["still.parquet"]), "--plot", str(work / "fit.png")]),
        }
        out_sizes = {p.name: p.stat().st_size / 1e6 for p in work.glob("*.*") if p.suffix in (".csv", ".parquet")}
        print()
        def t(key):
            return f"{res[key][0]:.1f} s wall, {res[key][1]:.1f} s CPU"

        print(f"| measure ({args.hours:g} h at 500 samples/s, one core) | plain-csv path | today | goal |")
        print("| --- | --- | --- | --- |")
        print(f"| `adxlgw estimate --method realtime`, CSV in, CSV out "
              f"| {old_w * scale:.0f} s wall, {old_c * scale:.0f} s CPU "
              f"(×{scale:g} the {args.baseline_hours:g} h run) | {t('csv')} | < 60 s |")
        print(f"| same, Parquet in and out | – | {t('pq')} | < 15 s |")
        print(f"| `adxlgw estimate --method smoothed`, Parquet | – | {t('smoothed')} | < 30 s |")
        print(f"| `adxlgw fit-drift` on a {args.hours:g} h standstill, Parquet | – | {t('fit')} | < 30 s |")
        print(f"| peak memory, realtime CSV / realtime Parquet / smoothed "
              f"| {old_m:.0f} MB on {args.baseline_hours:g} h | "
              f"{res['csv'][2]:.0f} / {res['pq'][2]:.0f} / {res['smoothed'][2]:.0f} MB "
              f"| < 500 MB / stated and checked |")
        print(f"| side by side on {args.baseline_hours:g} h, realtime CSV → CSV "
              f"| {old_w:.1f} s wall, {old_c:.1f} s CPU, "
              f"{old_m:.0f} MB | {new_w:.1f} s wall, {new_c:.1f} s CPU, {new_m:.0f} MB | "
              f"ratio {old_w / new_w:.1f}× wall, {old_c / new_c:.1f}× CPU |")
        print()
        print("file sizes (MB): " + ", ".join(f"{k} {v:.0f}" for k, v in sorted({**sizes, **out_sizes}.items())))
        print(f"smoothed: {res['smoothed'][2] * 1.048576e6 / (args.hours * 1800000):.0f} bytes of peak RSS per sample")
        fields = ("wall_s", "cpu_s", "peak_rss_mb")
        harness.write_json(args, {
            "hours": args.hours,
            "commands": {key: dict(zip(fields, value, strict=True)) for key, value in res.items()},
            "side_by_side": {"baseline_hours": args.baseline_hours,
                             "plain_csv_path": dict(zip(fields, (old_w, old_c, old_m), strict=True)),
                             "today": dict(zip(fields, (new_w, new_c, new_m), strict=True))},
        }, run)
    finally:
        used = sum(p.stat().st_size for p in work.rglob("*") if p.is_file()) / 1e9
        shutil.rmtree(work, ignore_errors=True)
        print(f"run cost: {time.perf_counter() - began:.0f} s wall; {used:.1f} GB in {work} at the end, deleted")
    return 0


if __name__ == "__main__":
    sys.exit(main())
