"""What `adxlgw diagnose` says: the text summary, the JSON form, and the Markdown report
with its plots (residual, spectrum, Allan deviation, position error, before and after).

Everything here reads a finished DiagnosisResult; nothing is computed twice except the
plots' spectra and Allan deviations, which the result keeps only in summary.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gateway.core.diagnosis import DiagnosisResult
from gateway.core.diagnosis.context import DRIFT_TIME_CONSTANT_S
from gateway.core.diagnosis.identifiability import what_separates
from gateway.errors import InputError
from gateway.offline.figures import save_figure

# side effects' residual RMS is not in m/s² (timing: seconds of host delay)
# the gain's residual_rms_<unit> key → (shown unit, factor)
_RMS_UNIT = {"mps2": ("m/s²", 1.0), "s": ("ms", 1e3)}
PLOTS = ("residual.png", "spectrum.png", "allan.png", "position.png")


# ---------------------------------------------------------------- JSON

def jsonable(value):
    """Plain JSON values: numpy scalars and arrays unwrapped, NaN and ±inf → None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return [jsonable(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return str(value)


# ---------------------------------------------------------------- numbers as text

def _num(x, fmt: str = ".4g") -> str:
    if x is None:
        return "–"
    x = float(x)
    if math.isnan(x):
        return "–"
    if math.isinf(x):
        return "−inf" if x < 0 else "inf"
    return format(x, fmt)


def _p(x) -> str:
    if x is None or not math.isfinite(float(x)):
        return "–"
    x = float(x)
    return "< 1e-300" if x == 0.0 else (f"{x:.2g}" if x < 0.01 else f"{x:.3f}")


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def drift_over_record(result: DiagnosisResult) -> float:
    """The drift term's change over this record (its amplitude is the asymptote of 1 − e^(−t/T))."""
    amp = result.baseline.get("drift_mps2", (float("nan"), 0.0))[0]
    return amp * -math.expm1(-result.duration_s / DRIFT_TIME_CONSTANT_S)


def params_text(params: dict) -> str:
    return ", ".join(f"{name} = {_num(v)} ± {_num(s, '.2g')}" for name, (v, s) in params.items())


def gain_lines(effect) -> list[str]:
    """The gain of one accepted effect: residual RMS, log-likelihood, distance error."""
    gain = effect.gain
    lines = []
    rms_key = next((k for k in gain if k.startswith("residual_rms")), None)
    if rms_key:
        unit, factor = _RMS_UNIT.get(rms_key.removeprefix("residual_rms_"), ("", 1.0))
        b, a = gain[rms_key]
        lines.append(f"residual RMS {_num(b * factor)} → {_num(a * factor)} {unit}".rstrip())
    if "loglik" in gain:
        b, a = gain["loglik"]
        lines.append(f"log-likelihood {_num(b, '.1f')} → {_num(a, '.1f')}")
    lines.append(distance_text(gain.get("distance")))
    return lines


def distance_text(dist: dict | None) -> str:
    if not dist:
        return "distance error: not computed"
    if "unsettled_mm" in dist:  # gain.distance_gain: measured, but one of several answers
        key = dist["metric"]
        b, a = dist["before"].get(key), dist["after"].get(key)
        return (f"distance error ({key}): {_num(b, '.3f')} → {_num(a, '.3f')} mm in the last pass: gain "
                f"{dist['why']}, counted neither for nor against")
    if not dist.get("available"):
        return f"distance error: not available ({dist.get('why', 'no reason given')})"
    key = dist["metric"]
    b, a = dist["before"].get(key), dist["after"].get(key)
    interval = dist.get("interval_mm")
    within = (f", interval {_num(interval[0], '+.2f')} … {_num(interval[1], '+.2f')} mm over the stops"
              if interval and interval[0] != interval[1] else "")
    return (f"distance error ({key}): {_num(b, '.3f')} → {_num(a, '.3f')} mm "
            f"(improvement {_num(dist.get('improvement_mm'), '+.3f')} mm{within})")


def summary_lines(result: DiagnosisResult, path: str) -> list[str]:
    ref = {"recorded": "recorded reference motion",
           "estimated": "none recorded: the smoothed estimate stands in for it"}.get(result.reference,
                                                                                     str(result.reference))
    off, off_s = result.baseline.get("offset_mps2", (float("nan"), float("nan")))
    dr, dr_s = result.baseline.get("drift_mps2", (float("nan"), float("nan")))
    return [
        f"diagnosis of {path}",
        f"reference: {ref}",
        f"samples: {result.n_samples}, {result.duration_s:.3f} s",
        f"baseline: offset {_num(off)} ± {_num(off_s, '.2g')} m/s², drift {_num(dr)} ± {_num(dr_s, '.2g')} m/s² "
        f"(amplitude of 1 − e^(−t/{DRIFT_TIME_CONSTANT_S:g} s): "
        f"{_num(drift_over_record(result))} m/s² over the record)",
        f"residual whiteness p: {_p(result.whiteness_p_before)} before → {_p(result.whiteness_p_after)} after",
        f"residual RMS: {_num(result.residual_rms_before)} → {_num(result.residual_rms_after)} m/s²"
        + (f" (means over {result.compare_block} samples: the reference's resolution)" if result.compare_block > 1
           else ""),
    ]


def verdict_line(result: DiagnosisResult) -> str:
    return f"residual white: {_yes(result.residual_white)}; unexplained structure remains: {_yes(result.unexplained)}"


def candidate_rows(result: DiagnosisResult) -> list[tuple[str, str, str, str, str]]:
    return [(c.name, c.status, _num(c.delta_bic, ".1f"), _p(c.p_value), c.reason) for c in result.candidates]


def side_lists(result: DiagnosisResult) -> list[tuple[str, list[str]]]:
    """The three lists beside the named effects, as (heading, lines)."""
    return [
        ("measured properties of the setup (inside what every setup has; kept in the model, not effects)",
         [f"{r['name']}: {r['what']}" for r in result.setup]),
        ("negligible (significant, but too small to matter)",
         [f"{r['name']}: {params_text(r['params'])} — {r['why']}" for r in result.negligible]),
        ("something of this shape, not physical as named — look elsewhere",
         [f"{r['shape']}: {r['why']} (ΔBIC {_num(r['delta_bic'], '.1f')})" for r in result.not_physical]),
    ]


def text_summary(result: DiagnosisResult, path: str) -> str:
    out = summary_lines(result, path)
    out.append("")
    if result.effects:
        out.append(f"effects found ({len(result.effects)}), in order of acceptance:")
        for e in result.effects:
            out.append(f"  {e.name} ({e.kind}): {params_text(e.params)}")
            detail = f"; {e.detail}" if e.detail else ""
            out.append(f"      ΔBIC {_num(e.delta_bic, '.1f')}, p {_p(e.p_value)}{detail}")
            if e.not_separable_from:
                out.append(f"      cannot be told apart here from: {', '.join(e.not_separable_from)} — the record fits "
                           f"them as well; {what_separates(e.name, e.not_separable_from[0])} would separate them")
            for line in gain_lines(e):
                out.append(f"      {line}")
    else:
        out.append("effects found: none")
    for heading, lines in side_lists(result):
        if lines:
            out.append("")
            out.append(f"{heading}:")
            out.extend(f"  {line}" for line in lines)
    out.append("")
    out.append("candidates:")
    rows = candidate_rows(result)
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(("effect", "status", "ΔBIC", "p"))]
    head = ("effect", "status", "ΔBIC", "p")
    out.append("  " + "  ".join(h.ljust(w) for h, w in zip(head, widths, strict=False)) + "  reason")
    for r in rows:
        cells = "  ".join(v.ljust(w) for v, w in zip(r[:4], widths, strict=False))
        out.append("  " + cells + ("  " + r[4] if r[4] else ""))
    if result.cannot:
        out.append("")
        out.append("cannot analyse:")
        out.extend(f"  - {c}" for c in result.cannot)
    if result.leftover:
        out.append("")
        out.append(f"left unexplained: {result.leftover['what']} ({100 * result.leftover['share']:.1f} % of the "
                   "residual variance): no smaller effect is named while it stands")
    host = (result.timestamps or {}).get("host")
    if host and not host["strictly_increasing"]:
        out.append("")
        out.append(f"host arrival times: {host['backwards']} backward steps, {host['zero_intervals']} zero intervals, "
                   f"{host['burst_intervals']} bursts in {host['rows']} rows (analysed as delays; no estimate on them)")
    if result.failures:
        out.append("")
        out.append("failed (each in isolation; the rest of the report stands):")
        out.extend(f"  - {f['what']}: {f['error']}" for f in result.failures)
    out.append("")
    out.append(verdict_line(result))
    return "\n".join(out)


# ---------------------------------------------------------------- plots

def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _period(result: DiagnosisResult) -> float:
    return float(np.median(np.diff(result.t_s)))


def _centred(r: np.ndarray) -> np.ndarray:
    r = np.asarray(r, dtype=float)
    good = np.isfinite(r)
    return np.where(good, r - (r[good].mean() if good.any() else 0.0), 0.0)


def plot_residual(result: DiagnosisResult, path: Path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True, sharey=True)
    for ax, r, label in ((axes[0], result.residual_before, "baseline model"),
                         (axes[1], result.residual_after, "extended model")):
        ax.plot(result.t_s, r, lw=0.5)
        ax.set_ylabel("residual (m/s²)")
        ax.set_title(f"{label}: RMS {_num(np.sqrt(np.nanmean(np.asarray(r) ** 2)))} m/s²", fontsize=10)
        ax.grid(alpha=0.3)
    axes[1].set_xlabel("time (s)")
    fig.tight_layout()
    save_figure(fig, path)


def plot_spectrum(result: DiagnosisResult, path: Path) -> None:
    from scipy.signal import welch

    plt = _plt()
    fs = 1.0 / _period(result)
    fig, ax = plt.subplots(figsize=(10, 5))
    for r, label in ((result.residual_before, "before (baseline)"), (result.residual_after, "after (extended)")):
        x = _centred(r)
        f, pxx = welch(x, fs=fs, nperseg=min(1024, max(16, x.size // 4)))
        ax.semilogy(f[1:], pxx[1:], lw=1, label=label)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of the residual ((m/s²)²/Hz)")
    ax.set_title("residual spectrum (Welch)")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    save_figure(fig, path)


def plot_allan(result: DiagnosisResult, path: Path) -> None:
    from gateway.core.drift_fit import allan_deviation

    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5))
    for r, label in ((result.residual_before, "before (baseline)"), (result.residual_after, "after (extended)")):
        a = allan_deviation(np.nan_to_num(np.asarray(r, dtype=float)), _period(result))
        ax.loglog(a.tau_s, a.adev, "o-", ms=3, label=label)
    ax.set_xlabel("τ (s)")
    ax.set_ylabel("Allan deviation of the residual (m/s²)")
    ax.set_title("Allan deviation (slope −½ white, 0 bias instability, +½ random walk)")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    save_figure(fig, path)


def plot_position(result: DiagnosisResult, path: Path, ref_pos_m: np.ndarray | None) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 5))
    drawn = False
    for key, label in (("before", "baseline model"), ("after", "extended model")):
        track = result.distance.get(key)
        if track is None:
            continue
        if ref_pos_m is not None:
            ax.plot(track.t_s, (track.pos_m - ref_pos_m) * 1e3, lw=1, label=label)
        else:
            ax.plot(track.t_s, track.pos_m * 1e3, lw=1, label=label)
        drawn = True
    if ref_pos_m is not None:
        ax.set_ylabel("position error: estimate − reference (mm)")
        ax.set_title("position error of the smoothed estimate, before and after the extension")
    else:
        ax.set_ylabel("position estimate (mm)")
        ax.set_title("smoothed position estimate (no reference recorded), before and after the extension")
    if not drawn:
        ax.text(0.5, 0.5, "no estimate: the estimator found no standstill to start from",
                ha="center", va="center", transform=ax.transAxes)
    else:
        ax.legend()
    ax.set_xlabel("time (s)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


# ---------------------------------------------------------------- Markdown

def _md_table(head: tuple[str, ...], rows) -> list[str]:
    def cell(v):
        return str(v).replace("|", "\\|")

    out = ["| " + " | ".join(head) + " |", "| " + " | ".join("---" for _ in head) + " |"]
    out.extend("| " + " | ".join(cell(v) for v in r) + " |" for r in rows)
    return out


def _screening_md(screening: dict) -> list[str]:
    out = []
    for when in ("before", "after"):
        s = screening.get(when, {})
        out.append(f"### Residual {when} the extension")
        out.append("")
        corr = s.get("correlations", [])[:6]
        if corr:
            out.append("Correlation of the whitened residual with candidate regressors (strongest first):")
            out.append("")
            out.extend(_md_table(("regressor", "r", "p"),
                                 [(c["regressor"], _num(c["correlation"], "+.3f"), _p(c["p_value"])) for c in corr]))
        else:
            out.append("No regressor to correlate with.")
        out.append("")
        peaks = s.get("spectrum_peaks", [])
        if peaks:
            out.append("Spectrum peaks (whitened residual, power over the median): "
                       + ", ".join(f"{_num(pk['frequency_hz'], '.1f')} Hz (×{_num(pk['power_ratio'], '.1f')})"
                                   for pk in peaks))
        else:
            out.append("Spectrum peaks: none above 6× the median.")
        allan = s.get("allan", [])
        if allan:
            out.append("")
            out.append("Allan slopes: " + ", ".join(f"τ {_num(a['tau_s'], '.3g')} s: {_num(a['slope'], '+.2f')}"
                                                     for a in allan))
        out.append("")
    return out


def report_markdown(result: DiagnosisResult, path: str, ref_kind: str) -> str:
    out = ["# Diagnosis: what the simulation gets wrong", ""]
    out.extend(f"- {line}" for line in summary_lines(result, f"`{path}`"))
    out += ["", f"**Verdict:** {verdict_line(result)}", ""]
    if result.cannot:
        out += ["## What cannot be analysed", ""]
        out.extend(f"- {c}" for c in result.cannot)
        out.append("")
    out += ["## Effects found", ""]
    if result.effects:
        rows = []
        for e in result.effects:
            g = gain_lines(e)
            rows.append((f"`{e.name}`", e.kind, params_text(e.params), _num(e.delta_bic, ".1f"), _p(e.p_value),
                         "<br>".join(g)))
        out.extend(_md_table(("effect", "kind", "parameters (± std)", "ΔBIC", "p", "gain"), rows))
        details = [f"- `{e.name}`: {e.detail}" for e in result.effects if e.detail]
        if details:
            out += [""] + details
    else:
        out.append("None: no candidate beat the baseline by the BIC margin and the likelihood-ratio test, "
                   "predicted the other half of the record, was physical and mattered.")
    for heading, lines in side_lists(result):
        if lines:
            out += ["", f"### {heading[0].upper()}{heading[1:]}", ""]
            out.extend(f"- {line}" for line in lines)
    out += ["", "## Candidates", ""]
    out.extend(_md_table(("effect", "status", "ΔBIC", "p", "reason"),
                         [(f"`{r[0]}`",) + r[1:] for r in candidate_rows(result)]))
    out += ["", "## Screening", ""]
    out.extend(_screening_md(result.screening))
    out += ["## Plots", "",
            "Residual (measured − model) of the baseline and of the extended model:", "",
            "![residual](residual.png)", "",
            "Its spectrum:", "", "![spectrum](spectrum.png)", "",
            "Its Allan deviation:", "", "![Allan deviation](allan.png)", "",
            ("Position error of the smoothed estimate against the recorded reference:" if ref_kind == "recorded"
             else "Position estimate (no reference was recorded):"), "",
            "![position](position.png)", ""]
    return "\n".join(out)


def write_report(directory: str, result: DiagnosisResult, recording_path: str,
                 ref_pos_m: np.ndarray | None) -> list[Path]:
    """DIR/report.md and the four plots; returns the files written."""
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"{directory}: cannot create the report directory: {err.strerror or err}") from err
    plot_residual(result, d / "residual.png")
    plot_spectrum(result, d / "spectrum.png")
    plot_allan(result, d / "allan.png")
    plot_position(result, d / "position.png", ref_pos_m)
    md = d / "report.md"
    try:
        md.write_text(report_markdown(result, recording_path, "recorded" if ref_pos_m is not None else "none"),
                      encoding="utf-8")
    except OSError as err:
        raise InputError(f"{md}: cannot write: {err.strerror or err}") from err
    return [md] + [d / name for name in PLOTS]
