"""How far a window's spread about its own mean tells rest from motion on the robot files.

    nice .venv/bin/python -m benchmarks.accuracy.window_spread [--window-s 0.1] [--json PATH]

A SHOE/GLRT-like detector judges a window by Σ(a − ā)²/σ² against χ² (its level absorbed
by the bias state), σ from the recording's quiet part (estimator settings from the rest, as
`adxlgw estimate` makes them). Per robot file (sensor clock, imported as the corpus
benchmark imports it): the windows' standard deviation about their own mean in units of
that σ, percentiles 10/50/90/99, inside the machine's rests and inside its moves (windows
wholly inside either), and the share of each that the variance test at the detector's
false-alarm rate passes.
"""
from __future__ import annotations

import sys

import numpy as np

from benchmarks import harness
from benchmarks.accuracy.estimation_corpus import ROBOT_FILES, robot_case


def spread_cells(sd, sigma: float, threshold: float) -> tuple[str, str]:
    """Percentiles of sd/σ and the share of windows within the variance test's bound."""
    pct = np.nanpercentile(sd / sigma, [10, 50, 90, 99])
    return " / ".join(f"{v:.1f}" for v in pct), f"{100 * np.mean(sd <= threshold):.0f} %"


def main() -> int:
    parser = harness.parser(__doc__)
    parser.add_argument("--window-s", type=float, default=0.1)
    args = parser.parse_args()
    run = harness.stamp(__spec__.name)
    print()
    rows = []
    print("| file | σ (quiet part) | rest windows: sd/σ p10 / p50 / p90 / p99 | pass | "
          "move windows: sd/σ p10 / p50 / p90 / p99 | pass |")
    print("| --- | --- | --- | --- | --- | --- |")
    from numpy.lib.stride_tricks import sliding_window_view

    for name in ROBOT_FILES:
        case = robot_case(name, "sensor")
        if case.error:
            print(f"| {case.name} | refused: {case.error} | | | | |")
            rows.append({"file": case.name, "refused": case.error})
            continue
        s = case.settings
        w = max(2, int(round(args.window_s / s.sample_period_s)))
        z = np.where(case.valid, case.acc_mps2, np.nan)
        sd = np.nanstd(sliding_window_view(z, w), axis=1, ddof=1)
        rest = sliding_window_view(case.rest, w).all(axis=1)
        moving = ~sliding_window_view(case.rest, w).any(axis=1)
        sigma = s.sample_noise_std_mps2
        threshold = np.sqrt(s.window_variance_threshold_mps2_sq)

        r, rp = spread_cells(sd[rest], sigma, threshold)
        m, mp = spread_cells(sd[moving], sigma, threshold)
        print(f"| {case.name} | {sigma / 9.80665 * 1e3:.2f} mg | {r} | {rp} | {m} | {mp} |")
        rows.append({"file": case.name, "sigma_mg": sigma / 9.80665 * 1e3, "rest_sd_over_sigma_p10_50_90_99": r,
                     "rest_pass": rp, "move_sd_over_sigma_p10_50_90_99": m, "move_pass": mp})
    harness.write_json(args, {"rows": rows}, run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
