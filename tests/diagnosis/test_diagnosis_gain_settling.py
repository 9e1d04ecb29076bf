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
import pytest

from gateway.core.diagnosis.gain import EstimatePlan, distance_gain
from gateway.core.diagnosis.judgement import distance_interval, matters
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


class _Fixed(EstimatePlan):
    """An estimator that ends at a given position (the record returns to its start)."""

    end_m: float = 0.0

    def run(self, t_s, acc, valid, lost):
        pos = np.zeros(acc.size)
        pos[-1] = self.end_m
        return SimpleNamespace(pos_m=pos, pos_std_m=np.full(acc.size, 1e-4), standstill=np.ones(acc.size, bool))


def test_an_unsettled_correction_is_no_gain_and_no_loss():
    """A gain is measured only where the model gives one answer: a correction whose passes
    did not settle is "not determined" — not a loss that keeps an effect from its name,
    nor a gain — and the JSON says so (determined: false, unsettled_mm)."""
    n = 100
    prep = _prep(n)
    prep.data.reference = "estimated"
    arrays = dict(t_s=np.arange(n) * 0.002, acc_mps2=np.zeros(n), valid=np.ones(n, bool),
                  lost_before=np.zeros(n, np.int64))
    before = _Fixed(settings=None, returns_to_start=True, **arrays)
    after = before._copy(unsettled_m=0.0164)
    after.end_m = 0.0049  # 4.9 mm off where it was 0: as one pass, a loss beyond any interval
    settled = distance_gain(prep, before, before._copy())
    assert settled["available"] and settled["determined"] and settled["improvement_mm"] == 0.0
    dist = distance_gain(prep, before, after)
    assert dist["determined"] is False and not dist["available"] and "improvement_mm" not in dist
    assert dist["unsettled_mm"] == pytest.approx(16.4) and "passes differ by 16.4 mm" in dist["why"]
    assert matters(dist) == (True, "")  # counted neither for nor against
    assert distance_interval(dist) is None
    # a chain whose earlier correction did not settle: its later gains are not determined either
    assert not distance_gain(prep, after, after._copy())["determined"]
    text = distance_text(dist)
    assert "not determined" in text and "16.4 mm" in text and "improvement" not in text


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
