"""Looking for what is wrong in a residual: whiteness, spectrum peaks, Allan slopes, and
its correlation with candidate regressors.

Everything is computed on the *whitened* residual (and regressors whitened by the same
filter), so a correlation's significance is not inflated by the sensor's own colouring.
Whiteness is judged on 10 ms block means: the 8051 timer's rounding repeats with the
fractional part of T2 in ticks — a line near 200 Hz that the baseline itself makes (the
simulator has it too) and that no motion effect lives at.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import find_peaks, welch
from scipy.stats import norm

from gateway.core.diagnosis.context import USABLE_COLUMN_FRACTION, Prepared
from gateway.core.diagnosis.criterion import ALPHA
from gateway.core.drift_fit import allan_deviation, ljung_box

WHITENESS_BLOCK_S = 0.01


def block_whiteness_p(prep: Prepared, whitened: np.ndarray) -> float:
    b = max(1, int(round(WHITENESS_BLOCK_S / prep.compare_period_s)))
    m = whitened[: whitened.size // b * b].reshape(-1, b).mean(axis=1)
    if m.size < 10:  # drift_fit.ljung_box's own floor: fewer and whiteness is not judged
        return float("nan")
    return ljung_box(m).p_value


def _welch_limit(prep: Prepared, whitened: np.ndarray, alpha: float, block: int = 1):
    """(f, pxx, level, limit): the whitened residual's Welch spectrum, the white level
    (from the median bin) and what white noise exceeds with probability alpha over all
    bins (each bin is the level × χ²₂ₖ/2K, K the half-overlapping segments averaged)."""
    from scipy.stats import chi2

    fs = 1.0 / (prep.compare_period_s * block)
    nperseg = min(1024, whitened.size // 4)
    f, pxx = welch(whitened, fs=fs, nperseg=nperseg)
    k = max(1, 2 * whitened.size // nperseg - 1)
    level = float(np.median(pxx)) / (float(chi2.median(2 * k)) / (2 * k))
    limit = level * float(chi2.isf(alpha / pxx.size, 2 * k)) / (2 * k)
    return f, pxx, level, limit


def spectrum_peaks(prep: Prepared, whitened: np.ndarray, top: int = 3) -> list[dict]:
    """The strongest lines of the whitened residual above white noise's level at ALPHA."""
    if whitened.size < 64:
        return []
    f, pxx, level, limit = _welch_limit(prep, whitened, ALPHA)
    idx, props = find_peaks(pxx, height=limit)
    order = np.argsort(-props["peak_heights"])[:top] if idx.size else []
    return [{"frequency_hz": float(f[idx[i]]), "power_ratio": float(props["peak_heights"][i] / level)} for i in order]


def spectrum_line(prep: Prepared, whitened: np.ndarray, alpha: float) -> dict | None:
    """The strongest spectral line of a whitened residual above what white noise reaches
    with probability alpha over all bins, with its share of the variance; None: none."""
    # on WHITENESS_BLOCK_S means, as whiteness is judged: the timer's rounding line (the
    # baseline's own, near 200 Hz and its aliases) is no structure an effect could explain
    b = max(1, int(round(WHITENESS_BLOCK_S / prep.compare_period_s)))
    whitened = whitened[: whitened.size // b * b].reshape(-1, b).mean(axis=1)
    if whitened.size < 64:  # 4 Welch segments of 16 at the least: fewer and no line is judged
        return None
    f, pxx, level, limit = _welch_limit(prep, whitened, alpha, b)
    i = int(np.argmax(pxx[1:])) + 1
    if pxx[i] <= limit:
        return None
    share = (float(pxx[i]) - level) / max(float(np.sum(pxx)), 1e-300)
    return {"what": f"a spectral line at {f[i]:.1f} Hz, {pxx[i] / level:.0f}× the level", "share": share}


def allan_slopes(prep: Prepared, residual: np.ndarray) -> list[dict]:
    r = np.nan_to_num(residual)
    if r.size < 64:
        return []
    a = allan_deviation(r, prep.data.period_s)
    slopes = np.diff(np.log(a.adev)) / np.diff(np.log(a.tau_s))
    return [{"tau_s": float(t), "adev_mps2": float(v), "slope": float(s)}
            for t, v, s in zip(a.tau_s[1:], a.adev[1:], slopes, strict=False)]


def candidate_regressors(prep: Prepared, reading: np.ndarray, pos: np.ndarray | None) -> dict[str, np.ndarray]:
    d = prep.data
    out: dict[str, np.ndarray] = {}
    if d.reference is not None:
        out["reference acceleration"] = reading
        out["reference acceleration²"] = reading**2
        out["jerk"] = np.gradient(reading, d.t_s)
        if pos is not None:
            out["position"] = pos
        if d.ref_vel_mps is not None:
            out["velocity"] = d.ref_vel_mps
    if d.other_mps2 is not None:
        out["other axis"] = d.other_mps2
    if d.temp_c is not None:
        out["temperature"] = d.temperature_c
    out["time"] = d.t_s - d.t_s[0]
    if d.t_host_s is not None:
        delay = d.t_host_s - d.t_s
        out["host timestamp irregularity"] = delay - np.nanmedian(delay)
    out["seq gaps"] = (d.lost_before > 0).astype(float)
    return out


def correlations(prep: Prepared, residual: np.ndarray, regressors: dict[str, np.ndarray]) -> list[dict]:
    m = prep.fit_mask
    w = prep.whiten_masked(np.nan_to_num(residual), m)
    w = w - w.mean()
    rows = []
    for name, x in regressors.items():
        x = np.asarray(x, dtype=float)
        good = np.isfinite(x)
        if good.mean() < USABLE_COLUMN_FRACTION:
            continue
        x = np.where(good, x, np.nanmean(x))
        if float(np.std(x[m])) == 0.0:
            continue
        wx = prep.whiten_masked(x - x[m].mean(), m)
        wx = wx - wx.mean()
        den = math.sqrt(float(np.dot(w, w)) * float(np.dot(wx, wx)))
        r = float(np.dot(w, wx)) / den if den > 0 else 0.0
        z = r * math.sqrt(w.size)
        rows.append({"regressor": name, "correlation": r, "p_value": float(2.0 * norm.sf(abs(z)))})
    rows.sort(key=lambda row: row["p_value"])
    return rows
