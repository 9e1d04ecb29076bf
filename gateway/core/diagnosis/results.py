"""The diagnosis's report: its records (each effect, each candidate, the whole result) and
how a computation that fails is recorded in it without losing the rest (`_isolated`)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

WHITE_ALPHA = 1e-3  # a 60 s record has 6000 blocks: a small misfit of the noise model must not read as a cause


@dataclass
class EffectResult:
    name: str
    kind: str  # "signal" or "side"
    params: dict[str, tuple[float, float]]
    p_value: float
    delta_bic: float
    gain: dict
    detail: str = ""
    # the causes that explain the same residual on this record as well (identifiability.py)
    not_separable_from: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind,
                "params": {k: [v, s] for k, (v, s) in self.params.items()},
                "p_value": self.p_value, "delta_bic": self.delta_bic, "gain": self.gain, "detail": self.detail,
                "not_separable_from": list(self.not_separable_from)}


@dataclass
class Candidate:
    name: str
    status: str  # accepted / rejected / not applicable
    delta_bic: float = float("nan")
    p_value: float = float("nan")
    reason: str = ""
    # a signal effect's parameters as last fitted (SI units, model_compensation's names),
    # named or not: what `diagnose --model-out --model-with NAME` writes for it
    model_params: dict = field(default_factory=dict)
    # the causes that explain the same residual on this record (named effects only)
    not_separable_from: list = field(default_factory=list)


@dataclass
class DiagnosisResult:
    reference: str | None
    n_samples: int
    duration_s: float
    baseline: dict[str, tuple[float, float]]
    noise_model: dict[str, float]
    effects: list[EffectResult]
    candidates: list[Candidate]
    whiteness_p_before: float
    whiteness_p_after: float
    residual_rms_before: float
    residual_rms_after: float
    screening: dict
    cannot: list[str]
    compare_block: int = 1  # model and measurement compared as means over this many samples
    setup: list[dict] = field(default_factory=list)  # measured properties of the setup (nuisance values)
    negligible: list[dict] = field(default_factory=list)  # significant, but too small to matter
    not_physical: list[dict] = field(default_factory=list)  # a shape that fits, with impossible values
    # the largest structure left in the final residual (leftover_structure), None: none
    leftover: dict | None = None
    # what the clocks are like (timestamps.HostClock), checked before the analysis
    timestamps: dict = field(default_factory=dict)
    # computations that failed, each in isolation: {"what": ..., "error": ...}; the rest stands
    failures: list[dict] = field(default_factory=list)
    # the extended model: the signal effects named or kept as the setup's, in order of
    # acceptance, parameters in SI units (`diagnose --model-out`, model_compensation)
    model_terms: list[dict] = field(default_factory=list)
    # for plots and the report (not in the JSON)
    t_s: np.ndarray = field(repr=False, default=None)
    residual_before: np.ndarray = field(repr=False, default=None)
    residual_after: np.ndarray = field(repr=False, default=None)
    distance: dict = field(repr=False, default_factory=dict)

    @property
    def residual_white(self) -> bool:
        return bool(self.whiteness_p_after > WHITE_ALPHA)

    @property
    def unexplained(self) -> bool:
        return not self.residual_white

    def to_dict(self) -> dict:
        return {
            "effects": [e.to_dict() for e in self.effects],
            "residual_white": self.residual_white,
            "unexplained": self.unexplained,
            "reference": self.reference,
            "samples": self.n_samples,
            "duration_s": self.duration_s,
            "baseline": {k: [v, s] for k, (v, s) in self.baseline.items()},
            "noise_model": self.noise_model,
            "whiteness_p": {"before": self.whiteness_p_before, "after": self.whiteness_p_after},
            "residual_rms_mps2": {"before": self.residual_rms_before, "after": self.residual_rms_after},
            "candidates": [c.__dict__ for c in self.candidates],
            "screening": self.screening,
            "cannot_analyse": self.cannot,
            "compare_block_samples": self.compare_block,
            "setup": self.setup,
            "negligible": self.negligible,
            "not_physical": self.not_physical,
            "timestamps": self.timestamps,
            "leftover": self.leftover,
            "failures": self.failures,
            "model_terms": self.model_terms,
        }


def _isolated(what: str, failures: list[dict], compute: Callable, fallback=None):
    """One computation of the report, in isolation: what it returns, or — when it fails
    (a bug, or an input no check foresaw) — `fallback` (default: a distance result that
    says why it is not available), the failure recorded in `failures`, and the rest of
    the report standing. A failure is never silent: the JSON and the text list it."""
    try:
        return compute()
    except Exception as err:  # noqa: BLE001 — isolation is the point; recorded below
        why = f"{what} failed: {type(err).__name__}: {err}"
        failures.append({"what": what, "error": f"{type(err).__name__}: {err}"})
        return {"available": False, "why": why} if fallback is None else fallback
