"""The `timing` side test alone on the own simulator: named when a buffering adapter and a
corrected host clock made the host times, and how often on clean records.

    .venv/bin/python -m benchmarks.accuracy.host_timing_benchmark --cases 200

Each case is testing.diagnosis_cases.make_case (seeds seed0 … seed0 + N − 1): clean
(the baseline link: UART + Exp(0.2 ms)), `timing_no_step` (the adapter and the slew
below, the clock not stepped: how often a step is kept that is not there), or `timing` (sensor_effects.TimingTerm at its
documented sizes: latency timer 4–16 ms, 62-byte packets, a clock step within ±30 ms, a
slew within ±500 ppm). The host delays go through the diagnosis's own test
(host_timing.host_delays, judge_timing at the side tests' false-alarm rate); the full
diagnosis (setup range, what matters) is diagnosis_benchmark's. Prints, per row, how
often the extension is predictive, how often a clock step is kept, and the errors of
the hold-back (against √12·σ of the adapter's waits), the step and the rate.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from benchmarks import harness
from gateway.core.diagnosis.criterion import ALPHA
from gateway.core.diagnosis.host_timing import TIMING_RESOLUTION_S, host_delays, judge_timing
from gateway.core.diagnosis.side_effects import SIDE_EFFECTS
from testing.diagnosis_cases import SENSOR, make_case


def one_case(row: str, seed: int) -> dict:
    # timing_no_step: the same adapter and slew, the clock never stepped
    unstepped = (lambda t: replace(t, clock_step_s=0.0)) if row == "timing_no_step" else None
    terms, data = make_case(() if row == "clean" else ("timing",), seed, adjust=unstepped)
    d = host_delays(data.t_s, data.t_host_s, data.lost_before, SENSOR.t2_s)
    alpha = ALPHA / len(SIDE_EFFECTS)
    v = judge_timing(d.delay_s, d.t_s, TIMING_RESOLUTION_S, alpha)
    out = {"seed": seed, "predictive": v.cv.predictive(alpha, v.extra_params), "step_kept": v.extra_params > 3,
           "hold_ms": v.fit.hold_s * 1e3, "step_ms": v.fit.step_s * 1e3, "rate_ppm": v.fit.rate * 1e6}
    if terms:
        t = terms[0]
        out.update(true_hold_ms=t.equivalent_hold_back_s() * 1e3, true_step_ms=t.clock_step_s * 1e3,
                   true_rate_ppm=t.clock_rate_error * 1e6)
    return out


def _median_p90(x) -> str:
    x = np.abs(np.asarray(x, dtype=float))
    return f"{np.median(x):.2f} / {np.quantile(x, 0.9):.2f}" if x.size else "–"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=50, help="cases per row")
    ap.add_argument("--seed0", type=int, default=0, help="first seed")
    ap.add_argument("--rows", default="timing,timing_no_step,clean",
                    help="comma-separated: timing, timing_no_step (the clock not stepped), clean")
    args = ap.parse_args(argv)
    harness.stamp("benchmarks.accuracy.host_timing_benchmark", argv)
    print("| row | extension predictive | clock step kept | hold-back error median / p90 (ms) "
          "| step error median / p90 (ms) | rate error median / p90 (ppm) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for row in args.rows.split(","):
        cases = [one_case(row, s) for s in range(args.seed0, args.seed0 + args.cases)]
        n = len(cases)
        pred = sum(c["predictive"] for c in cases)
        kept = sum(c["step_kept"] for c in cases)
        if row == "clean":
            print(f"| clean | {pred}/{n} | {kept}/{n} | – | – | – |")
            continue
        hold = [c["hold_ms"] - c["true_hold_ms"] for c in cases]
        step = [c["step_ms"] - c["true_step_ms"] for c in cases]
        rate = [c["rate_ppm"] - c["true_rate_ppm"] for c in cases]
        print(f"| {row} | {pred}/{n} | {kept}/{n} | {_median_p90(hold)} | {_median_p90(step)} | {_median_p90(rate)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
