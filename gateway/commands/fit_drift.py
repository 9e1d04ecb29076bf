"""adxlgw fit-drift: identify the zero-drift model from a standstill recording, judged as the paper does."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from gateway.commands.common import positive_float
from gateway.core.drift_fit import DriftFit, fit_drift
from gateway.core.units import STANDARD_GRAVITY_MPS2
from gateway.errors import InputError, RecordingError
from gateway.offline.figures import check_plot_path, save_figure
from gateway.offline.progress import reading_bar
from gateway.offline.recording import open_recording, read_all, to_acceleration


def add_parser(sub) -> None:
    p = sub.add_parser(
        "fit-drift",
        help="fit the zero-drift model ε(t) = C1(1 − e^(−t/T)) + C2 to a standstill recording",
        description="Fit C1, C2, T of the paper's zero-drift model to a standstill (the paper used 12 hours; "
                    "'adxlgw simulate --scenario standstill --duration S' makes one), print them with their "
                    "standard deviations, test whether the residual is white (Ljung–Box on block means), "
                    "read the noise terms from the residual's Allan deviation, and draw a plot.",
    )
    p.add_argument("recording", metavar="FILE.csv", help="the recording: CSV, or Parquet (.parquet)")
    p.add_argument("--block-s", type=positive_float, default=1.0,
                   help="block length for the fit and the whiteness test, s (default: 1)")
    p.add_argument("--plot", metavar="FILE.png", help="plot file (default: <recording name>_drift.png here)")
    p.add_argument("--model-out", metavar="DRIFT.json",
                   help="write the fitted model for 'adxlgw estimate --drift-model'")
    p.set_defaults(run=run)


def _ug(x_g: float | None, unit: str) -> str:
    return "not resolved" if x_g is None else f"{x_g * 1e6:.3g} {unit}"


def report(fit: DriftFit) -> list[str]:
    m = fit.model
    wb = fit.whiteness
    n = fit.noise
    verdict = ("white: the model explains the drift" if wb.white()
               else "NOT white: drift is left that the model does not explain")
    lines = [
        "zero-drift model ε(t) = C1·(1 − e^(−t/T)) + C2  (C2 includes the part's zero-g offset)",
        f"  C1 = {m.c1_g * 1e3:+.4f} ± {fit.c1_std_g * 1e3:.4f} mg",
        f"  C2 = {m.c2_g * 1e3:+.4f} ± {fit.c2_std_g * 1e3:.4f} mg",
        f"  T  = {m.time_constant_s:.1f} ± {fit.time_constant_std_s:.1f} s",
        f"residual: RMS {fit.residual_rms_g * 1e3:.3f} mg at full rate (lag-1 autocorrelation "
        f"{fit.full_rate_lag1:+.2f}: the sensor's own filter), {fit.block_residual_g.size} blocks of {fit.block_s:g} s",
        f"whiteness (Ljung–Box on the block residual, {wb.lags} lags): Q = {wb.statistic:.2f}, "
        f"p = {wb.p_value:.3g} → {verdict}",
        "Allan deviation of the residual, noise terms:",
        f"  white noise (slope −1/2):        N = {_ug(n.white_density_per_rthz, 'µg/√Hz')}",
        f"  bias instability (slope 0):      B = {_ug(n.bias_instability, 'µg')}"
        + (f" at τ = {n.bias_instability_tau_s:.3g} s" if n.bias_instability_tau_s else
           " (no flat minimum: the curve still falls where it is reliable)"),
        f"  rate random walk (slope +1/2):   K = {_ug(n.rate_random_walk_per_rts, 'µg/√s')}"
        + ("" if n.rate_random_walk_per_rts is not None else
           f" (bound from the longest τ: K ≤ {n.random_walk_bound_per_rts * 1e6:.3g} µg/√s)"),
    ]
    return lines


def plot_fit(path: str, fit: DriftFit, t0_s: float, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gateway.core.drift_model import drift_g

    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    t = fit.block_t_s - t0_s
    ax = axes[0, 0]
    ax.plot(t, fit.block_mean_g * 1e3, ".", ms=2, label=f"{fit.block_s:g} s means")
    ax.plot(t, drift_g(t, fit.model) * 1e3, "r", label="fitted ε(t)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("acceleration at rest (mg)")
    ax.legend()
    ax = axes[0, 1]
    ax.plot(t, fit.block_residual_g * 1e6, ".", ms=2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("residual of the block means (µg)")
    ax = axes[1, 0]
    lags = np.arange(fit.acf.size)
    ax.bar(lags[1:], fit.acf[1:], width=0.6)
    bound = 1.96 / math.sqrt(fit.whiteness.n)
    ax.axhline(bound, color="r", ls="--")
    ax.axhline(-bound, color="r", ls="--", label="95 % bounds for white noise")
    ax.set_xlabel("lag (blocks)")
    ax.set_ylabel("autocorrelation")
    ax.set_title(f"Ljung–Box Q = {fit.whiteness.statistic:.1f}, p = {fit.whiteness.p_value:.3g}", fontsize=10)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    tau, adev = fit.allan.tau_s, fit.allan.adev
    ax.loglog(tau, adev * 1e6, "o-", ms=3, label="Allan deviation of the residual")
    n = fit.noise
    if n.white_density_per_rthz:
        ax.loglog(tau, n.white_density_per_rthz / np.sqrt(2 * tau) * 1e6, "--", label="N/√(2τ)")
    if n.bias_instability:
        ax.axhline(0.664 * n.bias_instability * 1e6, ls=":", color="g", label="0.664·B")
    k = n.rate_random_walk_per_rts or n.random_walk_bound_per_rts
    ax.loglog(tau, k * np.sqrt(tau / 3) * 1e6, ":",
              label="K·√(τ/3)" + ("" if n.rate_random_walk_per_rts else " (bound)"))
    ax.set_xlabel("τ (s)")
    ax.set_ylabel("σ_A (µg)")
    ax.legend(fontsize=8)
    ax.grid(which="both", alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    plot_path = args.plot or f"{Path(args.recording).stem}_drift.png"
    check_plot_path(plot_path)  # before the work
    source = open_recording(args.recording)
    # the fit needs the time and the measured axis only: the reference, the host's arrival
    # time and the temperature are not read (~40 bytes per sample less)
    wanted = [n for n in source.names if not n.startswith("ref_") and n not in ("t_host_s", "temp_c")]
    with reading_bar(source) as bar:
        series = to_acceleration(read_all(source, columns=wanted, progress=bar))
    for w in series.report.warnings():
        print(f"adxlgw fit-drift: warning: {w}", file=sys.stderr)
    acc_g = np.where(series.valid, series.acc_mps2, np.nan) / STANDARD_GRAVITY_MPS2
    try:
        fit = fit_drift(series.t_s, acc_g, block_s=args.block_s)
    except (ValueError, RuntimeError) as err:  # RuntimeError: curve_fit did not converge
        raise RecordingError(f"{args.recording}: cannot fit the drift model: {err}") from err
    for line in report(fit):
        print(line)
    plot_fit(plot_path, fit, float(series.t_s[0]), f"zero drift of {Path(args.recording).name}")
    print(f"wrote {plot_path}")
    if args.model_out:
        try:
            with open(args.model_out, "w", encoding="utf-8") as fh:
                json.dump(fit.fitted().to_dict(), fh, indent=2)
                fh.write("\n")
        except OSError as err:
            raise InputError(f"{args.model_out}: cannot write: {err.strerror or err}") from err
        print(f"wrote {args.model_out}")
    return 0
