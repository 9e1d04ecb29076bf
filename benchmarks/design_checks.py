"""The design checks of 2026-11-26 (fourth session) that docs/diagnosis.md and
docs/estimation.md quote, on the simulator and the design robot file:

    PYTHONPATH=. .venv/bin/python benchmarks/design_checks.py

1. timing, the simulator's own cases (paper strokes, seeds 0–19): the delay residual's RMS
   before and after the extension (its "share" is ~0 for any latency timer), and the
   distance gains; gentle strokes (0.5 m/s, 2 m/s², seed 0): the distance gain and the
   position a host-stamped sample carries at top speed;
2. a bias random walk hidden in strokes with 4 s rests (seeds 1–5): named from the rests;
3. the robot-like path at 100 Hz, 0.1 m/s², a 5 mg step (seeds 0–2): realtime error at the
   rest ends against 3σ;
4. the design robot file (eV50p) with the robot's hint: realtime error at the rest ends,
   the machine's "moving" with its latency (0.1 s) and as a veto from its first sample (0);
5. (fifth session) clean cases on parts as built (tests/diagnosis_cases.part_within_tolerance,
   seeds 0–19): the output filter and sensitivity the diagnosis measures, against the part;
6. (sixth session) the simulator's 0.08 s hinted stop (tests/test_estimation_hint, seeds 0–7,
   the test's): realtime position error at the stop's end without and with the hint.
"""
from __future__ import annotations

import contextlib
import datetime
import io
import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.machine_info import machine  # noqa: E402
from gateway.cli import main as adxlgw  # noqa: E402
from gateway.commands.estimate import settings_for  # noqa: E402
from gateway.core import estimator_kernel as K  # noqa: E402
from gateway.core.estimator import estimate_series  # noqa: E402
from gateway.core.motion_profiles import StrokeSettings  # noqa: E402
from gateway.core.runs import true_runs  # noqa: E402
from gateway.offline.recording import read_recording, to_acceleration  # noqa: E402
from tests.diagnosis_cases import SENSOR, STROKES, make_case, part_within_tolerance, run_diagnosis  # noqa: E402
from tests.robot_like_cases import robot_case  # noqa: E402
from tests.test_diagnosis_walk_at_rest import LONG_DWELLS  # noqa: E402
from tests.test_estimation_hint import SETTINGS as HINT_SETTINGS  # noqa: E402
from tests.test_estimation_hint import _short_stop_case  # noqa: E402 (after the sys.path line, like the rest)


def timing() -> None:
    rms, gains = [], []
    for seed in range(20):
        _, data = make_case(("timing",), seed)
        (e,) = [x for x in run_diagnosis(data).effects if x.name == "timing"]
        rms.append(e.gain["residual_rms_s"])
        gains.append(e.gain["distance"]["improvement_mm"])
    ratio = [after / before for before, after in rms]
    print(f"1. timing, paper strokes, seeds 0–19: delay residual RMS after/before {min(ratio):.5f}–{max(ratio):.5f} "
          f"(seed 0: {rms[0][0] * 1e3:.4f} → {rms[0][1] * 1e3:.4f} ms); "
          f"distance gains {min(gains):.1f}–{max(gains):.1f} mm")
    gentle = StrokeSettings(strokes=STROKES, max_speed_mps=0.5, max_acc_mps2=2.0)
    terms, data = make_case(("timing",), 0, strokes=gentle)
    result = run_diagnosis(data)
    (e,) = [x for x in result.effects if x.name == "timing"]
    print(f"   gentle strokes, seed 0 (a {terms[0].hold_s * 1e3:.2f} ms timer): distance gain "
          f"{e.gain['distance']['improvement_mm']:+.2f} mm, position at top speed {e.gain['position_mm']:.2f} mm")


def walk() -> None:
    named = []
    for seed in range(1, 6):
        terms, data = make_case(("bias_random_walk",), seed, strokes=LONG_DWELLS)
        names = [x.name for x in run_diagnosis(data).effects]
        named.append(f"{seed}: {'named' if names == ['bias_random_walk'] else names or 'nothing'}")
    print("2. a walk hidden in strokes with 4 s rests, seeds 1–5: " + "; ".join(named))


def robot_like() -> None:
    ratios = []
    for seed in range(3):
        t, z, ref, resting, settings = robot_case(seed, 5.0, rate_hz=100.0, noise_mps2=0.1)
        tr = estimate_series(t, z, method="realtime", settings=settings)
        ends = [b - 1 for a, b in true_runs(resting) if a > 0]
        ratios += [abs(tr.pos_m[i] - ref[i]) / (3 * tr.pos_std_m[i]) for i in ends]
    print("3. robot-like 100 Hz, 0.1 m/s², 5 mg, seeds 0–2: |error| / 3σ at the rest ends "
          + ", ".join(f"{r:.2f}" for r in ratios))
    # why: the filter's bias against the final rest's mean (the offset after the step), in
    # its own σ, and the smallest offset error one window's mean test can see
    for seed in range(3):
        t, z, ref, resting, settings = robot_case(seed, 5.0, rate_hz=100.0, noise_mps2=0.1)
        prm = settings.kernel_params()
        state = K.new_state(prm)
        for k in range(t.size):
            K.step(state, prm, t[k], z[k], True, 0)
        final_rest = true_runs(resting)[-1]
        truth = float(np.mean(z[final_rest[0]:final_rest[1]]))
        bias, bias_std = state.out[K.O_BIAS], float(np.sqrt(state.out[K.O_BIAS_VAR]))
        seen = prm[K.P_MEAN_SIGMAS] * np.sqrt(prm[K.P_R] / settings.window_samples + bias_std**2)
        print(f"   seed {seed}: bias at the end {bias:.4f} m/s², the final rest's mean {truth:.4f}: off by "
              f"{(truth - bias) / bias_std:.1f} σ_b (σ_b {bias_std:.4f}); "
              f"the mean test sees an offset error beyond {seen:.3f} m/s² (the step: {5e-3 * 9.80665:.3f})")


def robot_hint() -> None:
    source = ROOT / "datasets" / "leiria-robot" / "eV50p_MPU6050RM3100.csv"
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "imported.csv")
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            adxlgw(["import", str(source), "--time-col", "sensor_time_s", "--acc-col", "acc_z_g", "--acc-unit", "g",
                    "--out", path])
        series = to_acceleration(read_recording(path))
    raw = np.genfromtxt(source, delimiter=",", names=True)
    ref, hint = raw["ref_z_m"], raw["robot_at_rest"]
    settings = settings_for(series, "acceleration", "auto", None)
    ends = [b - 1 for a, b in true_runs(hint > 0.5)]
    for label, s, h in (("no hint", settings, None), ("hint, latency 0.1 s", settings, hint),
                        ("hint, latency 0 (a veto)", replace(settings, hint_latency_s=0.0), hint)):
        tr = estimate_series(series.t_s, series.acc_mps2, series.valid, method="realtime", settings=s,
                             standstill_hint=h)
        print(f"4. eV50p realtime, {label}: error at the rest ends (mm) "
              + ", ".join(f"{(tr.pos_m[i] - ref[i]) * 1e3:+.1f}" for i in ends))


def setup_properties() -> None:
    """Clean cases on parts as built: what the diagnosis measures of the setup against the part."""
    bw_err, scale_err, named = [], [], []
    for seed in range(20):
        part = part_within_tolerance(seed)
        _, data = make_case((), seed, part=part)
        result = run_diagnosis(data)
        props = {x["name"]: x["params"] for x in result.setup}
        bw = props.get("output_filter", {}).get("bandwidth_hz", (SENSOR.bandwidth_hz, 0.0))[0]
        s = props.get("scale_factor", {}).get("scale_error_frac", (0.0, 0.0))[0]
        s = next((e.params["scale_error_frac"][0] for e in result.effects if e.name == "scale_factor"), s)
        bw_err.append(bw - part.bandwidth_hz)
        scale_err.append(s - part.x.sensitivity_error_frac)
        named += [f"seed {seed}: {e.name}" for e in result.effects]
    print(f"5. clean cases on parts as built (sensitivity ±1 %, CX ±10 %), seeds 0–19: output filter − the part's "
          f"{min(bw_err):+.2f} … {max(bw_err):+.2f} Hz; sensitivity − the part's {100 * min(scale_err):+.3f} … "
          f"{100 * max(scale_err):+.3f} % (within 0.03 %: {sum(abs(e) <= 3e-4 for e in scale_err)} of 20); named: "
          + (", ".join(named) or "nothing"))


def short_hinted_stop() -> None:
    plain_err, hint_err, ratio = [], [], []
    for seed in range(8):
        run, t, z, resting = _short_stop_case(seed)
        end = np.flatnonzero(resting & (t > 2.5) & (t < t[-1] - 2.5))[-1]
        plain = estimate_series(t, z, method="realtime", settings=HINT_SETTINGS)
        hinted = estimate_series(t, z, method="realtime", settings=HINT_SETTINGS,
                                 standstill_hint=resting.astype(float))
        plain_err.append(plain.pos_m[end] - run.ref_pos_m[end])
        hint_err.append(hinted.pos_m[end] - run.ref_pos_m[end])
        ratio.append(abs(hint_err[-1]) / (3 * hinted.pos_std_m[end]))
    rms = [1e3 * float(np.sqrt(np.mean(np.square(e)))) for e in (plain_err, hint_err)]
    print(f"6. a 0.08 s hinted stop (simulator, seeds 0–7): realtime error at its end RMS {rms[0]:.2f} mm without "
          f"the hint, {rms[1]:.2f} mm with it; |error| / 3σ at most {max(ratio):.2f}")


def main() -> None:
    print("command: PYTHONPATH=. .venv/bin/python benchmarks/design_checks.py")
    print(f"date:    {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {machine()}")
    timing()
    walk()
    robot_like()
    robot_hint()
    setup_properties()
    short_hinted_stop()


if __name__ == "__main__":
    main()
