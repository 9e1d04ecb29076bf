"""How fast the estimators run: a 12-hour recording offline, and one realtime step.

    python -m benchmarks.speed.estimator_speed [--hours 12]

Side by side with another checkout: `python -m benchmarks.tools.compare speed --compare DIR`
(side_by_side below): each checkout's own code run by this interpreter in a child process
on the same recording, the checkouts alternating, --repeats rounds; CPU time (not wall
time) per sample of the offline realtime and smoothed estimates (the realtime one is the
kernel's step in a compiled loop, as the daemon's pipeline runs it) and of
RealtimeEstimator.step called from Python; the minimum and the median over the rounds,
and each checkout's median against this one's.

The 12-hour recording is made in memory by the simulator (no CSV): the paper's strokes
(0.3 m at 1 m/s, 1 s dwells) back to back for the whole time, at exactly 500 samples/s
(T2 = 2.000 ms). The process is pinned to one core. Times exclude the simulation and
the one-off numba compilation (measured and printed separately: with numba's cache it
is paid once per installation, not per run).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import harness
from gateway.core import estimator_kernel as K
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import RealtimeEstimator, estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.jit import JIT_ENABLED
from gateway.core.motion_profiles import StrokeSettings, reciprocating_strokes
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate

REPO = Path(__file__).resolve().parents[2]


def twelve_hours(hours: float, sensor: SensorParams):
    stroke_s = 0.4 + 1.0
    strokes = int(np.ceil(hours * 3600 / stroke_s))
    profile = reciprocating_strokes(StrokeSettings(strokes=strokes))
    run = simulate(profile, sensor, seed=0, duration_s=hours * 3600 - sensor.t2_s / 2)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    return t, z, float(run.ref_pos_m[-1])


# run inside each checkout (its own gateway): only APIs every version has
SIDE_BY_SIDE_PROBE = r'''
import json, os, sys, time
import numpy as np
from gateway.core.estimator import RealtimeEstimator, estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.sensor_model import SensorParams
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
with np.load(sys.argv[1]) as data:
    t, z = data["t"], data["z"]
n_step = int(sys.argv[2])
settings = from_sensor_model(SensorParams(t2_error_frac=0.0))
lost = np.zeros(t.size, np.int64)
estimate_series(t[:5000], z[:5000], method="smoothed", settings=settings, lost_before=lost[:5000])  # compile/load
out = {}
for method in ("realtime", "smoothed"):
    start = time.process_time()
    estimate_series(t, z, method=method, settings=settings, lost_before=lost)
    out[f"offline {method} ns/sample"] = (time.process_time() - start) / t.size * 1e9
est = RealtimeEstimator(settings)
start = time.process_time()
for k in range(n_step):
    est.step(float(t[k]), float(z[k]))
out["RealtimeEstimator.step µs/sample"] = (time.process_time() - start) / n_step * 1e6
print(json.dumps(out))
'''


def side_by_side(checkouts: list[Path], hours: float, repeats: int, n_step: int = 50_000) -> dict:
    """Each checkout's CPU time per sample on one recording, alternating; printed as a table."""
    t, z, _ = twelve_hours(hours, SensorParams(t2_error_frac=0.0))
    times: dict[Path, dict[str, list[float]]] = {c: {} for c in checkouts}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "recording.npz"
        np.savez(data, t=t, z=z)
        for _ in range(repeats):
            for checkout in checkouts:
                env = {**os.environ, "PYTHONPATH": str(checkout)}
                done = subprocess.run([sys.executable, "-c", SIDE_BY_SIDE_PROBE, str(data), str(min(n_step, t.size))],
                                      cwd=checkout, env=env, capture_output=True, text=True, check=True)
                for key, value in json.loads(done.stdout.strip().splitlines()[-1]).items():
                    times[checkout].setdefault(key, []).append(value)
    print(f"{t.size / 1e6:.2f} M samples ({hours:g} h of the paper's strokes at 500 samples/s), {repeats} rounds; "
          "CPU time per sample, min / median, and the median against this checkout's")
    keys = list(times[checkouts[0]])
    print("| checkout | " + " | ".join(keys) + " |")
    print("|" + " --- |" * (len(keys) + 1))
    medians = {c: {k: statistics.median(v) for k, v in times[c].items()} for c in checkouts}
    for checkout in checkouts:
        cells = [f"{min(times[checkout][k]):.3g} / {medians[checkout][k]:.3g} "
                 f"({medians[checkout][k] / medians[checkouts[0]][k]:.2f}×)" for k in keys]
        print(f"| {'this checkout' if checkout == checkouts[0] else checkout} | " + " | ".join(cells) + " |")
    return {str(c): times[c] for c in checkouts}


def main() -> int:
    parser = harness.parser(__doc__)
    parser.add_argument("--hours", type=float, default=12.0)
    parser.add_argument("--realtime-samples", type=int, default=200_000)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    run = harness.stamp("benchmarks.speed.estimator_speed")
    print(f"pinned to 1 of {os.cpu_count()} cores; numba {'on' if JIT_ENABLED else 'OFF (plain Python loops)'}")
    results: dict[str, float] = {}
    sensor = SensorParams(t2_error_frac=0.0)  # exactly 500 samples/s
    settings = from_sensor_model(sensor)

    start = time.perf_counter()
    t, z, _ = twelve_hours(0.01, sensor)
    estimate_series(t, z, method="smoothed", settings=settings)
    print(f"first call (numba compile or cache load) + a 36 s run: {time.perf_counter() - start:.2f} s")

    start = time.perf_counter()
    t, z, final_truth = twelve_hours(args.hours, sensor)
    print(f"simulated {t.size / 1e6:.2f} M samples ({t[-1] / 3600:.2f} h) in {time.perf_counter() - start:.1f} s "
          "(not counted)")
    lost = np.zeros(t.size, np.int64)
    for method in ("realtime", "smoothed"):
        start = time.perf_counter()
        track = estimate_series(t, z, method=method, settings=settings, lost_before=lost)
        elapsed = time.perf_counter() - start
        results[f"offline_{method}_ns_per_sample"] = elapsed / t.size * 1e9
        print(f"offline {method:9s}: {elapsed:6.1f} s for {t.size / 1e6:.2f} M samples "
              f"({elapsed / t.size * 1e9:.0f} ns/sample); standstill {100 * track.standstill.mean():.0f} % "
              f"of the time; final position error {(track.pos_m[-1] - final_truth) * 1e3:+.1f} mm")
        del track

    n = min(args.realtime_samples, t.size)
    est = RealtimeEstimator(settings)
    start = time.perf_counter()
    for k in range(n):
        est.step(t[k], z[k])
    per_step = (time.perf_counter() - start) / n
    print(f"realtime RealtimeEstimator.step: {per_step * 1e6:.2f} µs/sample → "
          f"{per_step * 500 * 100:.2f} % of one core at 500 samples/s")
    prm = settings.kernel_params()
    state = K.new_state(prm)
    start = time.perf_counter()
    for k in range(n):
        K.step(state, prm, t[k], z[k], True, 0)
    kernel = (time.perf_counter() - start) / n
    results.update(realtime_step_us=per_step * 1e6, kernel_step_us=kernel * 1e6)
    print(f"  of which the kernel call itself: {kernel * 1e6:.2f} µs/sample (the rest builds the Estimate)")
    # without numba: the same code as plain Python, in a fresh interpreter
    probe = (
        "import time, numpy as np; from gateway.core.estimator import RealtimeEstimator;"
        "from gateway.core.estimator_settings import from_sensor_model;"
        "from gateway.core.sensor_model import SensorParams;"
        "e = RealtimeEstimator(from_sensor_model(SensorParams(t2_error_frac=0.0)));"
        "z = 0.1 + np.random.default_rng(0).normal(0, 0.02, 20000); s = time.perf_counter();"
        "[e.step(k * 0.002, z[k]) for k in range(20000)];"
        "print((time.perf_counter() - s) / 20000)"
    )
    env = dict(os.environ, ADXLGW_NO_JIT="1", PYTHONPATH=str(REPO))
    py = float(subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                              check=True).stdout)
    print(f"without numba (ADXLGW_NO_JIT=1, plain Python): {py * 1e6:.1f} µs/sample → {py * 500 * 100:.1f} % of "
          f"a core at 500 samples/s; a 12-hour offline run would take ~{py * 21.6e6 / 60:.0f} min (realtime) "
          "and about 1.6× that smoothed")
    results["plain_python_step_us"] = py * 1e6
    harness.write_json(args, results, run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
