"""A distance gain measured on a correction whose passes did not settle says so.

Tilt and motion offset are corrected with the estimate's own position and motion flags,
re-estimated pass after pass (gain.EstimatePlan). Where the estimate's standstill
decisions flip with the correction the passes alternate between answers (the Leiria
robot's horizontal moves: SENTRAL with an offset while moving, hinted, 16 mm apart;
unhinted, up to a metre): the distance after is then one of them, not the model's, and
the gain carries how far the last pass still moved (docs/diagnosis.md §6, §9).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from gateway.core.diagnosis.gain import EstimatePlan
from gateway.core.diagnosis.signal_effects import Tilt
from gateway.offline.diagnosis_report import distance_text


class _FlippingEstimate(EstimatePlan):
    """An estimator whose decision flips with the sign of what it is fed."""

    def run(self, t_s, acc, valid, lost):
        return SimpleNamespace(pos_m=np.full(acc.size, 0.1 if acc.mean() > 0 else -0.1),
                               standstill=np.zeros(acc.size, bool))


class _Data(SimpleNamespace):
    def __len__(self):
        return self.t_s.size


def _prep(n):
    t = np.arange(n) * 0.002
    return SimpleNamespace(data=_Data(t_s=t, other_mps2=None, temperature_c=None), rest=np.zeros(n, bool))


def test_a_correction_that_alternates_is_marked_unsettled():
    n = 100
    plan = _FlippingEstimate(settings=None, t_s=np.arange(n) * 0.002, acc_mps2=np.zeros(n),
                             valid=np.ones(n, bool), lost_before=np.zeros(n, np.int64))
    corrected = plan._compensated(_prep(n), plan, Tilt(), np.array([0.01]))
    assert corrected.unsettled_m == 0.2


def test_a_correction_that_settles_is_not_marked():
    class Still(EstimatePlan):
        def run(self, t_s, acc, valid, lost):
            return SimpleNamespace(pos_m=np.zeros(acc.size), standstill=np.ones(acc.size, bool))

    n = 100
    plan = Still(settings=None, t_s=np.arange(n) * 0.002, acc_mps2=np.zeros(n), valid=np.ones(n, bool),
                 lost_before=np.zeros(n, np.int64))
    assert plan._compensated(_prep(n), plan, Tilt(), np.array([0.01])).unsettled_m == 0.0


def test_the_report_says_the_distance_did_not_settle():
    dist = {"available": True, "metric": "final_mm", "before": {"final_mm": -5.7}, "after": {"final_mm": -10.6},
            "improvement_mm": -4.9, "unsettled_mm": 16.4}
    assert "did not settle" in distance_text(dist) and "16.4 mm" in distance_text(dist)
    del dist["unsettled_mm"]
    assert "did not settle" not in distance_text(dist)


def test_the_diagnosis_and_estimate_model_make_the_same_passes():
    """The re-estimation is written once (model_compensation.settle_correction): the
    diagnosis's gain and `adxlgw estimate --model` run the estimator as often, stop at the
    same settle limit and end on the same corrected acceleration."""
    from gateway.core.model_compensation import ModelTerm, SampleContext, SensorModel, compensated_estimate

    n, kappa = 100, 0.01
    runs = {"diagnosis": 0, "estimate": 0}

    def contracting(acc, who):
        # each pass moves the position by ~κ·g = 0.098 of the last pass's move: the passes
        # settle after a few, and a settle limit ten times finer takes one pass more
        runs[who] += 1
        return SimpleNamespace(pos_m=np.full(acc.size, float(acc.mean())), standstill=np.zeros(acc.size, bool))

    class Contracting(EstimatePlan):
        def run(self, t_s, acc, valid, lost):
            return contracting(acc, "diagnosis")

    acc = np.ones(n)
    plan = Contracting(settings=None, t_s=np.arange(n) * 0.002, acc_mps2=acc, valid=np.ones(n, bool),
                       lost_before=np.zeros(n, np.int64))
    corrected = plan._compensated(_prep(n), plan, Tilt(), np.array([kappa]))
    corrected.track(_prep(n))  # the last pass's track is the plan's: no further run
    model = SensorModel((ModelTerm("tilt", {"tilt_gradient_rad_per_m": kappa}),))
    result = compensated_estimate(model, acc, SampleContext(np.arange(n) * 0.002),
                                  lambda a: contracting(a, "estimate"))
    assert result.settled and corrected.unsettled_m == 0.0
    assert runs["diagnosis"] == runs["estimate"] == result.passes
    assert np.array_equal(corrected.acc_mps2, result.acc_mps2)
