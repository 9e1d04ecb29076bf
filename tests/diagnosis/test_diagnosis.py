"""The diagnosis finds effects it is not told about, and its parts agree with independent sums.

Cases (testing/diagnosis_cases.py): a simulated 4-stroke recording (a 60 s standstill for
bias_random_walk) with one or two effects of gateway.core.sensor_effects hidden in it,
parameters drawn at the documented sizes from a seeded generator; diagnose gets only
the recording. Seeds here are 9000+, never the benchmark's (0…N−1), so the tests are
not the data the tolerances came from.
"""
from __future__ import annotations

import ast
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm

from gateway.core.diagnosis.context import DiagnosisInput, Prepared, prepare
from gateway.core.diagnosis.criterion import block_predictive_loglik
from gateway.core.diagnosis.model_fit import fit_model
from gateway.core.diagnosis.reading import WHITE, gaussian_loglik, sensor_reading
from gateway.core.diagnosis.screening import correlations
from gateway.core.diagnosis.side_effects import local_level_loglik
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.scenarios import ScenarioSettings, build_profile
from gateway.core.simulator import period_mean_lowpass
from testing.diagnosis_cases import CHECKS, EFFECTS, SENSOR, make_case, run_case

ROOT = Path(__file__).resolve().parents[2]
SINGLE_SEEDS = (9000, 9001)
CLEAN_SEEDS = (9100, 9101, 9102, 9103, 9104)
PAIRS = (("scale_factor", "temperature_offset"), ("vibration", "sample_loss"), ("tilt", "timing"))
PAIR_SEED = 9050


def _single_id(param) -> str:
    name, seed = param
    return f"{name}-{seed}"


# --- (a) one effect hidden: named, parameters within tolerance, positive gain, nothing else named


@pytest.mark.slow
@pytest.mark.parametrize("case", [(n, s) for n in EFFECTS for s in SINGLE_SEEDS], ids=_single_id)
def test_one_hidden_effect_is_named_and_estimated(case):
    name, seed = case
    out = run_case((name,), seed)
    report = out.describe()
    effect = out.effects[name]
    assert effect.named, f"{name} not named\n{report}"
    assert not out.wrong, f"also named {list(out.wrong)}\n{report}"
    assert len(effect.params) == len(CHECKS[name])
    for p in effect.params:
        assert p.ok, f"{p.key}: {p.estimate:.6g} vs true {p.truth:.6g}, tolerance ±{p.tolerance:.3g}\n{report}"
    assert effect.gain_positive, f"gain not positive {effect.gain_why}\n{report}"


# --- (b) two effects at once: both named, both estimated


@pytest.mark.slow
@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: "+".join(p))
def test_two_hidden_effects_are_both_named(pair):
    out = run_case(pair, PAIR_SEED)
    report = out.describe()
    for name in pair:
        effect = out.effects[name]
        assert effect.named, f"{name} not named\n{report}"
        for p in effect.params:
            assert p.ok, f"{name} {p.key}: {p.estimate:.6g} vs true {p.truth:.6g}, ±{p.tolerance:.3g}\n{report}"
        assert effect.gain_positive, f"{name}: gain not positive {effect.gain_why}\n{report}"


# --- (c) a clean recording: no effect, and the baseline leaves a white residual


@pytest.mark.slow
def test_clean_recordings_name_nothing_and_are_mostly_white():
    # "white" is a test at p > 1e-3 on a slightly misspecified noise model (the 8051
    # timer's rounding repeats with T2's fractional tick and beats against the 10 ms
    # blocks): over 30 clean seeds 29 read white. So every clean seed must name nothing,
    # and at least 4 of these 5 must read white.
    outs = [run_case((), seed) for seed in CLEAN_SEEDS]
    for out in outs:
        assert out.named == (), f"clean recording, seed {out.seed}: named {list(out.named)}"
    white = [out.seed for out in outs if out.residual_white]
    assert len(white) >= len(CLEAN_SEEDS) - 1, f"white only for seeds {white} of {list(CLEAN_SEEDS)}"


# --- (d) the code under test is never told the answer

# either generator: the simulator and its effects, or the independent one in testing/
FORBIDDEN = ("gateway.core.sensor_effects", "gateway.core.simulator", "gateway.core.motion_profiles",
             "testing", "tests")


def _imported_modules(path: Path) -> list[str]:
    """Absolute names of everything a module imports (relative imports resolved)."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            names.append(module)
            names += [f"{module}.{a.name}" for a in node.names]  # from gateway.core import simulator
    return names


DIAGNOSIS_FILES = sorted((ROOT / "gateway" / "core" / "diagnosis").rglob("*.py"))


@pytest.mark.parametrize("path", DIAGNOSIS_FILES, ids=lambda p: p.name)
def test_diagnosis_never_imports_the_simulated_effects(path):
    for name in _imported_modules(path):
        for forbidden in FORBIDDEN:
            assert not (name == forbidden or name.startswith(forbidden + ".")), f"{path.name} imports {name}"


def test_diagnosis_does_not_load_the_simulated_effects_even_indirectly():
    code = ("import sys, gateway.core.diagnosis, gateway.core.diagnosis.selection; "
            f"print([m for m in {FORBIDDEN!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", f"importing the diagnosis loads {out.stdout.strip()}"


# --- (e) parts against independent computations


def _prepared(n: int, mask: np.ndarray, rng) -> Prepared:
    t = np.arange(n) * 0.002
    data = DiagnosisInput(t, rng.standard_normal(n), np.ones(n, bool), np.zeros(n, np.int64))
    return Prepared(data, np.zeros(n), mask.copy(), np.zeros(n), mask.copy(), noise=WHITE)


def test_correlations_match_numpy_corrcoef_for_white_noise():
    rng = np.random.default_rng(11)
    n = 2000
    mask = rng.random(n) > 0.1  # some samples left out of the fit
    prep = _prepared(n, mask, rng)
    residual = rng.standard_normal(n)
    related = 0.3 * residual + rng.standard_normal(n)
    unrelated = rng.standard_normal(n)
    gappy = 0.2 * residual + rng.standard_normal(n)
    gappy[rng.choice(n, 50, replace=False)] = np.nan  # 2.5 % missing: filled with the mean
    too_gappy = rng.standard_normal(n)
    too_gappy[: n // 5] = np.nan  # 20 % missing: left out
    constant = np.ones(n)
    regs = {"related": related, "unrelated": unrelated, "gappy": gappy, "too gappy": too_gappy, "constant": constant}
    rows = {r["regressor"]: r for r in correlations(prep, residual, regs)}
    assert set(rows) == {"related", "unrelated", "gappy"}
    m = mask
    for name in ("related", "unrelated", "gappy"):
        x = regs[name]
        x = np.where(np.isfinite(x), x, np.nanmean(x))
        r = np.corrcoef(residual[m], x[m])[0, 1]
        assert rows[name]["correlation"] == pytest.approx(r, abs=1e-12)
        assert rows[name]["p_value"] == pytest.approx(2.0 * norm.sf(abs(r) * math.sqrt(m.sum())), rel=1e-9)
    assert rows["related"]["p_value"] < 1e-20 and rows["unrelated"]["p_value"] > 1e-3


def test_sensor_reading_matches_the_simulators_period_mean_of_a_profile():
    """The diagnosis rebuilds the reading from the recorded reference; the simulator from the profile."""
    profile = build_profile(ScenarioSettings(strokes=StrokeSettings(strokes=2)))
    period = SENSOR.t2_s
    n = int(np.floor(profile.duration_s / period)) + 1
    t = np.arange(n) * period
    _, vel, acc = profile.evaluate(t)
    expected = period_mean_lowpass(profile, n, period, SENSOR.bandwidth_hz)
    got = sensor_reading(t, vel, acc, SENSOR.bandwidth_hz)
    assert np.abs(acc).max() > 5.0  # the profile moves, with steps inside periods
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("k", [0.0, 0.05, 0.4, 3.0])
def test_local_level_loglik_is_the_exact_gaussian_density(k):
    """y_i = L_i + e_i, e_i ~ N(0, σ²), L_i = L_(i−1) + w_i, w_i ~ N(0, K²·dt).

    With the first level diffuse, the likelihood is that of y_1…y_(n−1) given y_0: then
    L_0 | y_0 ~ N(y_0, σ²), and d_i = y_i − y_0 (i ≥ 1) is normal with mean 0 and
    Cov(d_i, d_j) = σ²·(1 + δij) + K²·dt·min(i, j). (Not the plain white-noise density
    of y − y_0 even for K = 0: every d_i shares e_0.)
    """
    rng = np.random.default_rng(5)
    n, dt, sigma = 30, 0.25, 0.2
    y = 0.7 + np.cumsum(rng.standard_normal(n)) * max(k, 0.1) * math.sqrt(dt) + sigma * rng.standard_normal(n)
    i = np.arange(1, n)
    cov = sigma**2 * (1.0 + np.eye(n - 1)) + k * k * dt * np.minimum.outer(i, i)
    brute = multivariate_normal(np.zeros(n - 1), cov).logpdf(y[1:] - y[0])
    assert local_level_loglik(y, dt, k, sigma) == pytest.approx(brute, rel=1e-10, abs=1e-9)
    # a fold left out (how the walk's out-of-fold fit sees the record): the density of the
    # values used, the others skipped — the marginal of the same Gaussian
    use = np.ones(n, dtype=bool)
    use[10:15] = False
    kept = use[1:]
    marginal = multivariate_normal(np.zeros(kept.sum()), cov[np.ix_(kept, kept)]).logpdf((y[1:] - y[0])[kept])
    assert local_level_loglik(y, dt, k, sigma, use) == pytest.approx(marginal, rel=1e-10, abs=1e-9)


def test_block_press_residuals_are_the_refit_without_the_block():
    """The criterion's out-of-block prediction of a linear model (criterion.py) against
    refitting by least squares on the other blocks and predicting the block left out."""
    rng = np.random.default_rng(8)
    n = 300
    x = np.column_stack([np.ones(n), np.linspace(0, 1, n), rng.standard_normal(n)])
    y = x @ np.array([0.3, -1.0, 0.5]) + rng.standard_normal(n)
    ids = np.repeat(np.arange(20), n // 20)
    resid = y - x @ np.linalg.lstsq(x, y, rcond=None)[0]
    got = block_predictive_loglik(resid, x, ids)
    var = float(np.dot(resid, resid)) / n  # the criterion scores both ways under the fit's own variance
    for b in range(20):
        out = ids == b
        coef = np.linalg.lstsq(x[~out], y[~out], rcond=None)[0]
        e = y[out] - x[out] @ coef
        expected = float(np.sum(-0.5 * (np.log(2 * np.pi * var) + e**2 / var)))
        assert got[b] == pytest.approx(expected, rel=1e-9)


def test_model_fit_without_effects_is_least_squares_offset_and_drift():
    _, data = make_case((), 9200)
    prep = prepare(data)
    fit = fit_model(prep, ())
    m = prep.fit_mask
    x = np.column_stack([np.ones(int(m.sum())), prep.drift_shape[m]])
    y = data.acc_mps2[m] - prep.reading_mps2[m]
    coef = np.linalg.lstsq(x, y, rcond=None)[0]
    np.testing.assert_allclose(fit.theta, coef, rtol=1e-9, atol=1e-12)
    residual = y - x @ coef
    np.testing.assert_allclose(fit.residual[m], residual, rtol=0, atol=1e-9)
    assert np.all(np.isnan(fit.residual[~m]))
    # white noise model: the log-likelihood is the normal one with the ML variance
    var = float(np.mean(residual**2))
    assert fit.loglik == pytest.approx(-0.5 * residual.size * (math.log(2 * math.pi * var) + 1.0), rel=1e-10)
    assert fit.loglik == pytest.approx(gaussian_loglik(residual), rel=1e-12)
